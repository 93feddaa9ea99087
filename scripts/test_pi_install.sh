#!/usr/bin/env bash
# The Raspberry Pi OS install (docs/install-pi.md) tested on this Debian 12 machine, which has
# Bookworm's numpy 1.24: scripts/install_pi.sh into a venv in a temp folder, then numpy and PyAV
# must still be Debian's (and a plain `pip install .` in a new venv must be seen to replace numpy,
# the failure this guards against) and `antiscatter run` must work. Then pip's resolution of the package's
# dependencies for the Pi itself (aarch64) beside each release's system numpy: Bookworm's
# (Python 3.11, numpy 1.24.2) and Trixie's (Python 3.13, numpy 2.2.4), so bounds that exclude
# either fail here. Needs root or sudo (apt) and PyPI. Used by .ci/run.
set -euo pipefail
cd "$(dirname "$0")/.."
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
venv="$tmp/venv"

bash scripts/install_pi.sh "$venv"

debian_numpy=$(dpkg-query -W -f='${Version}' python3-numpy | sed 's/^[0-9]*://; s/[-+~].*$//')
"$venv/bin/python" - "$debian_numpy" <<'EOF'
import sys
import numpy
assert numpy.__file__.startswith("/usr/lib/python3/dist-packages/"), numpy.__file__
assert numpy.__version__ == sys.argv[1], (numpy.__version__, sys.argv[1])
print(f"ok: numpy {numpy.__version__} is Debian's ({numpy.__file__})")
EOF

# Negative control: in a new venv without the constraint, pip would put a numpy over Debian's.
/usr/bin/python3 -m venv --system-site-packages "$tmp/plain"
"$tmp/plain/bin/pip" install -q --dry-run --report "$tmp/plain.json" . 2>/dev/null
"$venv/bin/python" - "$tmp/plain.json" <<'EOF'
import json, sys
got = {item["metadata"]["name"]: item["metadata"]["version"] for item in json.load(open(sys.argv[1]))["install"]}
assert "numpy" in got, f"a plain pip install would keep the system numpy now: {got}"
print(f"ok: without the constraint pip would install numpy {got['numpy']} over Debian's")
EOF

(cd "$tmp" && "$venv/bin/antiscatter" run sim --frames 30 --output none >"$tmp/run.txt")
grep -q "frames per second" "$tmp/run.txt" || { cat "$tmp/run.txt"; echo "run printed no summary" >&2; exit 1; }
echo "ok: antiscatter run sim --frames 30 --output none"

# The dependencies as pyproject.toml states them, resolved for the Pi's aarch64 wheels.
mapfile -t deps < <("$venv/bin/python" -c '
import tomllib
print("\n".join(tomllib.load(open("pyproject.toml", "rb"))["project"]["dependencies"]))')
platforms=()
for glibc in 17 24 26 27 28 31 34 35 36; do platforms+=(--platform "manylinux_2_${glibc}_aarch64"); done
for release in "bookworm 3.11 1.24.2" "trixie 3.13 2.2.4"; do
    read -r name python numpy <<<"$release"
    echo "numpy==$numpy" >"$tmp/$name.txt"
    "$venv/bin/pip" install -q --dry-run --ignore-installed --only-binary=:all: --target "$tmp/$name" \
        --python-version "$python" "${platforms[@]}" -c "$tmp/$name.txt" \
        --report "$tmp/$name.json" "${deps[@]}"
    "$venv/bin/python" - "$tmp/$name.json" "$name" <<'EOF'
import json, sys
got = {item["metadata"]["name"]: item["metadata"]["version"] for item in json.load(open(sys.argv[1]))["install"]}
print(f"ok: {sys.argv[2]} (aarch64) resolves: " + ", ".join(f"{k} {v}" for k, v in sorted(got.items())))
EOF
done
