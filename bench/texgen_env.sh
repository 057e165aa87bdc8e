#!/usr/bin/env bash
# texgen_env.sh [--check | --fenicsx-env]: print the path of a Python that has TexGen (PyPI pytexgen
# 1.2.1 and the numpy it needs), building a virtual environment for it once.
#
#   bench/texgen_env.sh                 a venv of this system's python3 (on the host: the host's)
#   bench/texgen_env.sh --check         only print the venv's python if it is there and works, else exit 1
#   bench/texgen_env.sh --fenicsx-env   (on the host) the same for the FEniCSx environment: the venv is
#                                       made inside it, from its python3 (3.13), with wheels that the
#                                       host's pip downloads; prints the path as seen inside it
#
# The venv is $TEXTILE_FENICSX_CACHE/pytexgen-venv (default /var/cache/textile-fenicsx) of the system
# that runs the script. A venv works only with the interpreter it was made from, and the FEniCSx chroot
# sees neither the host's /var/cache nor its python, so the tests and the bench (which run inside the
# environment) need the --fenicsx-env venv; inside the chroot it lives in the chroot's own file system
# (under the cached root, so it goes, and is made again, when bin/fenicsx-env rebuilds the root). The
# path printed is then the same string on both sides, /var/cache/textile-fenicsx/pytexgen-venv/bin/python,
# naming the host's venv on the host and the environment's inside it.
# numpy: < 2.1 below Python 3.13, >= 2.1, < 2.3 on 3.13 (the pins of pytexgen 1.2.1's own wheels).
# TexGen is never a run-time dependency of textile_fenicsx: only bench/texgen.py and its tests use it.
#
# Environment:
#   TEXTILE_FENICSX_CACHE               where the venv is kept (default /var/cache/textile-fenicsx); it is
#                                       also where bin/fenicsx-env keeps its root (4 GB), so with
#                                       --fenicsx-env a new value means a new root
#   TEXTILE_FENICSX_TEXGEN_BASE_PYTHON  the python to make it with (default /usr/bin/python3, else
#                                       python3 on PATH)
#   TEXTILE_FENICSX_TEXGEN_WHEELS       install from the wheels in this folder, without PyPI
# Output: the venv's python on stdout (nothing else); progress and errors on stderr; exit 1 on failure.
set -euo pipefail

say() { printf 'texgen_env: %s\n' "$*" >&2; }
die() { say "error: $*"; exit 1; }

MODE=build
case "${1:-}" in
    "") ;;
    --check) MODE=check ;;
    --fenicsx-env) MODE=fenicsx-env ;;
    --base-info) MODE=base-info ;;  # internal: "X.Y machine glibc" of the python the venv is made from
    -h|--help) awk 'NR > 1 && !/^#/ { exit } NR > 1 { sub(/^# ?/, ""); print }' "${BASH_SOURCE[0]}"; exit 0 ;;
    *) die "unexpected argument '$1' (try --help)" ;;
esac
[ $# -le 1 ] || die "one option at most (try --help)"

REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd -P)
CACHE=${TEXTILE_FENICSX_CACHE:-/var/cache/textile-fenicsx}
VENV=$CACHE/pytexgen-venv
STAMP=.texgen-env

if [ -n "${TEXTILE_FENICSX_TEXGEN_BASE_PYTHON:-}" ]; then
    BASE=$TEXTILE_FENICSX_TEXGEN_BASE_PYTHON
elif [ -x /usr/bin/python3 ]; then
    BASE=/usr/bin/python3
else
    BASE=$(command -v python3 || true)
fi
[ -n "$BASE" ] && [ -x "$BASE" ] || die "no python3 found to make the pytexgen venv with \
(looked for /usr/bin/python3 and python3 on PATH; or set TEXTILE_FENICSX_TEXGEN_BASE_PYTHON)"

requirements() {  # requirements X.Y: what to install for Python X.Y, one per line
    echo "pytexgen==1.2.1"
    case "$1" in
        3.[0-9]|3.1[0-2]) echo "numpy<2.1" ;;
        3.13) echo "numpy>=2.1,<2.3" ;;
        *) echo "numpy>=2.3" ;;
    esac
}

# ---- --fenicsx-env: on the host, make the venv inside the FEniCSx environment --------------------
if [ "$MODE" = fenicsx-env ]; then
    ENVCMD=$REPO/bin/fenicsx-env
    [ -x "$ENVCMD" ] || die "$ENVCMD is missing"
    if path=$("$ENVCMD" "$REPO/bench/texgen_env.sh" --check); then
        echo "$path"
        exit 0
    fi
    # The environment's pip may not reach PyPI (no network, or a proxy whose certificate only the host
    # trusts), so the host's pip fetches the wheels into /tmp, which the environment sees.
    info=$("$ENVCMD" "$REPO/bench/texgen_env.sh" --base-info) \
        || die "cannot run python3 in the FEniCSx environment ($ENVCMD)"
    read -r pyver arch glibc <<<"$info"
    "$BASE" -m pip --version >/dev/null 2>&1 || die "the host's $BASE has no pip to download the wheels with"
    platforms=()
    for ((m = ${glibc#*.}; m >= 17; m--)); do platforms+=(--platform "manylinux_2_${m}_$arch"); done
    wheels=$(mktemp -d /tmp/texgen-wheels.XXXXXX) || die "cannot make a folder in /tmp"
    trap 'rm -rf "$wheels"' EXIT
    say "downloading the wheels for Python $pyver ($arch, glibc $glibc) with the host's pip"
    mapfile -t reqs < <(requirements "$pyver")
    if ! out=$("$BASE" -m pip download --disable-pip-version-check --no-input --no-deps \
        --only-binary=:all: --python-version "$pyver" --implementation cp --abi "cp${pyver/./}" \
        "${platforms[@]}" -d "$wheels" "${reqs[@]}" 2>&1); then
        printf '%s\n' "$out" | tail -n 15 | sed 's/^/texgen_env:   | /' >&2
        die "the host's pip could not download ${reqs[*]} for Python $pyver"
    fi
    TEXTILE_FENICSX_TEXGEN_WHEELS=$wheels "$ENVCMD" "$REPO/bench/texgen_env.sh"
    exit $?
fi

# ---- this system's python ----------------------------------------------------------------------
if [ "$MODE" = base-info ]; then
    "$BASE" -c 'import os, platform, sys
print("%d.%d" % sys.version_info[:2], platform.machine(), os.confstr("CS_GNU_LIBC_VERSION").split()[1])' \
        || die "$BASE does not run, or this is no glibc system"
    exit 0
fi
base_id=$("$BASE" -c 'import platform, sys; print(sys.executable, platform.python_version())' 2>/dev/null) \
    || die "$BASE does not run"
pyver=$("$BASE" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
mapfile -t REQS < <(requirements "$pyver")
want="${REQS[*]} | $base_id"   # what the venv was made from; another interpreter or pins: remade

usable() {  # usable DIR: DIR is a finished venv for $want whose python imports TexGen
    [ -x "$1/bin/python" ] && [ "$(cat "$1/$STAMP" 2>/dev/null)" = "$want" ] &&
        "$1/bin/python" -c 'import numpy, pytexgen.Core' >/dev/null 2>&1
}

if usable "$VENV"; then
    echo "$VENV/bin/python"
    exit 0
fi
[ "$MODE" = build ] || exit 1  # --check: quietly

mkdir -p "$CACHE" 2>/dev/null || die "cannot create the cache folder $CACHE (set TEXTILE_FENICSX_CACHE)"
[ -w "$CACHE" ] || die "the cache folder $CACHE is not writable (set TEXTILE_FENICSX_CACHE)"
command -v flock >/dev/null || die "flock (util-linux) is needed"
exec 9>"$CACHE/.pytexgen-venv.lock" || die "cannot open the lock file $CACHE/.pytexgen-venv.lock"
if ! flock -n 9; then
    say "another texgen_env.sh is making $VENV; waiting for it"
    flock 9
fi
if usable "$VENV"; then  # made by the one we waited for
    echo "$VENV/bin/python"
    exit 0
fi

tmp=$(mktemp -d "$CACHE/.pytexgen-venv.XXXXXX") || die "cannot make a temporary folder in $CACHE"
chmod 755 "$tmp"
trap 'rm -rf "$tmp"' EXIT
log=$CACHE/pytexgen-venv.log
: >"$log"
say "making $VENV with $base_id: ${REQS[*]} (once; under a minute)"

fail() {  # fail MESSAGE: report with the end of the log; the temporary folder goes with the trap
    tail -n 15 "$log" | sed 's/^/texgen_env:   | /' >&2
    die "$1 (full log: $log); nothing was kept"
}

# Debian's python3 has ensurepip only with python3-venv (the FEniCSx root lacks it); then the venv is
# made without pip and the system's pip (pip >= 22.3: --python) installs into it.
pip=("$tmp/bin/python" -m pip)
if ! "$BASE" -m venv "$tmp" >>"$log" 2>&1; then
    rm -rf "$tmp" && mkdir "$tmp"
    "$BASE" -m venv --without-pip "$tmp" >>"$log" 2>&1 || fail "$BASE -m venv failed"
    "$BASE" -m pip --version >>"$log" 2>&1 || fail "$BASE has neither ensurepip nor pip \
(on Debian: apt-get install python3-venv, or python3-pip)"
    pip=("$BASE" -m pip --python "$tmp/bin/python")
fi
source=()
if [ -n "${TEXTILE_FENICSX_TEXGEN_WHEELS:-}" ]; then
    [ -d "$TEXTILE_FENICSX_TEXGEN_WHEELS" ] \
        || fail "TEXTILE_FENICSX_TEXGEN_WHEELS=$TEXTILE_FENICSX_TEXGEN_WHEELS is not a folder"
    source=(--no-index --find-links "$TEXTILE_FENICSX_TEXGEN_WHEELS")
fi
"${pip[@]}" install --disable-pip-version-check --no-input --only-binary=:all: "${source[@]}" "${REQS[@]}" \
    >>"$log" 2>&1 || fail "pip could not install ${REQS[*]} (no network? a proxy this system does not \
trust? then run bench/texgen_env.sh --fenicsx-env on the host, or set TEXTILE_FENICSX_TEXGEN_WHEELS)"
"$tmp/bin/python" -c 'import numpy, pytexgen.Core' >>"$log" 2>&1 \
    || fail "pytexgen was installed but does not import"

# The venv's own scripts (pip, activate) name the folder they were made in; point them at the final one.
grep -lIr --null -F "$tmp" "$tmp/bin" 2>/dev/null | xargs -0 -r sed -i "s|$tmp|$VENV|g"
echo "$want" >"$tmp/$STAMP"
rm -rf "$VENV"
mv "$tmp" "$VENV" || die "cannot move the new venv to $VENV"
trap - EXIT
usable "$VENV" || die "the venv at $VENV does not work after the move (see $log)"
say "ready: $VENV"
echo "$VENV/bin/python"
