"""Regression datasets from the digital twin: specs, samples, the Dask engine, the make job.

Modules: :mod:`.spec` (the TOML spec, seeded draws per sample), :mod:`.sample`
(one sample: the pipelined frame loop into PNG frame folders or the Zarr store),
:mod:`.engine` (in-process, local Dask cluster or a running scheduler),
:mod:`.make` (the whole job: checks, resume, retries, index, ledger, card).
Reading datasets, verifying them and scoring detectors needs no renderer and
lives in :mod:`scheimpflug.dataset`.
"""

from .engine import Engine, EngineError
from .make import STORAGES, MakeResult, make_dataset
from .spec import DatasetSpec, SamplePlan, load_spec, parse_spec, plan_sample, sample_seed

__all__ = [
    "STORAGES",
    "DatasetSpec",
    "Engine",
    "EngineError",
    "MakeResult",
    "SamplePlan",
    "load_spec",
    "make_dataset",
    "parse_spec",
    "plan_sample",
    "sample_seed",
]
