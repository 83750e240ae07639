#!/usr/bin/env bash
# One entry point that sets everything up (idempotently) and then runs a job.
#   bash run.sh demo [ARGS...]   the main job: the paper's experiments in the twin
#   bash run.sh test [ARGS...]   the test suite (pytest)
#   bash run.sh docs [ARGS...]   the documentation site into docs/_build/html (Sphinx, warnings are errors,
#                                the gallery run, internal links checked; ARGS go to sphinx-build)
#   bash run.sh CMD  [ARGS...]   any `scheimpflug` subcommand, e.g. design --preset paper
# Set-up: Debian's libllvm19 (Mitsuba's CPU JIT needs libLLVM >= 17) when run as
# root with apt (and for `test` Debian's chromium, which the studio's browser tests drive), a virtual
# environment in .venv, and the project installed into it.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="$here/.venv"
log() { printf 'run.sh: %s\n' "$*" >&2; }

have_llvm17() {
    local f
    for f in /usr/lib/*/libLLVM.so.{17,18,19,20,21}* /usr/lib/*/libLLVM-{17,18,19,20,21}*.so* \
             /usr/lib/llvm-{17,18,19,20,21}/lib/libLLVM*.so*; do
        [ -e "$f" ] && return 0
    done
    return 1
}

if ! have_llvm17; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        log "installing Debian's libllvm19 (Mitsuba's CPU JIT needs libLLVM >= 17)"
        if ! { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null; }; then
            log "WARNING: could not install libllvm19; the renderer will fall back to Mitsuba's slow scalar variant"
        fi
    else
        log "WARNING: no libLLVM >= 17 found and not root with apt; the renderer will fall back to Mitsuba's slow scalar variant"
    fi
fi

py="${PYTHON:-}"
if [ -z "$py" ]; then
    for cand in python3.11 python3 python; do
        if command -v "$cand" >/dev/null 2>&1; then py="$cand"; break; fi
    done
fi
if [ ! -x "$venv/bin/python" ]; then
    log "creating the virtual environment in .venv"
    "$py" -m venv "$venv"
fi
stamp="$venv/.installed-$(cat "$here/pyproject.toml" | sha256sum | cut -c1-16)"
if [ ! -f "$stamp" ]; then
    log "installing the project and its dependencies into .venv (first run takes a few minutes)"
    "$venv/bin/python" -m pip install -q --upgrade pip >/dev/null
    "$venv/bin/python" -m pip install -q -e "$here[test,docs]"
    rm -f "$venv"/.installed-*
    touch "$stamp"
fi

job="${1:-demo}"
[ $# -gt 0 ] && shift
# The studio's browser tests (tests/test_studio_browser.py) drive Debian's Chromium through Playwright
# (the test extra; its own browser download needs the internet): installed for `test` when absent.
if [ "$job" = test ] && ! command -v chromium >/dev/null 2>&1; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        log "installing Debian's chromium (the studio's browser tests)"
        if ! { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; }; then
            log "WARNING: could not install chromium; the studio's browser tests will be skipped"
        fi
    else
        log "WARNING: no chromium and not root with apt; the studio's browser tests will be skipped"
    fi
fi
cd "$here"
case "$job" in
    test) exec "$venv/bin/python" -m pytest "$@" ;;
    docs) "$venv/bin/python" -m sphinx -b html -W --keep-going -j 2 -q docs docs/_build/html "$@"
          exec "$venv/bin/python" docs/_ext/scheimpflug_docs.py check-links docs/_build/html ;;
    *)    exec "$venv/bin/scheimpflug" "$job" "$@" ;;
esac
