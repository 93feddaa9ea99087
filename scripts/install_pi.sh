#!/usr/bin/env bash
# Install antiscatter on Raspberry Pi OS Bookworm (Debian 12) or Trixie (Debian 13) so that pip never
# shadows the system's numpy, which python3-picamera2 and its helpers are built against
# (docs/install-pi.md says why and gives the same steps by hand).
#   bash scripts/install_pi.sh [VENV]      (VENV defaults to .venv; run from anywhere in the repo)
# Debian's numpy and PyAV (and Picamera2 and kms++ where apt has them: Raspberry Pi OS) come from apt;
# a venv made with --system-site-packages sees them; pip installs the rest with numpy pinned to the
# system's own version, and the script fails if numpy or PyAV end up anywhere but the system's.
set -euo pipefail
cd "$(dirname "$0")/.."
venv=${1:-.venv}
system_site=/usr/lib/python3/dist-packages

if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
packages=(python3-venv python3-numpy python3-av)
for extra in python3-picamera2 python3-kms++; do  # the camera and output kms: Raspberry Pi OS's archive
    if apt-cache show "$extra" >/dev/null 2>&1; then packages+=("$extra"); fi
done
echo "apt: ${packages[*]}"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${packages[@]}" >/dev/null

# Debian's own python3 (3.11 on Bookworm, 3.13 on Trixie): the one its numpy is built for.
/usr/bin/python3 -m venv --system-site-packages "$venv"
constraints="$venv/system-numpy.txt"
"$venv/bin/python" -c 'import numpy; print(f"numpy=={numpy.__version__}")' >"$constraints"
echo "pip: constraint $(cat "$constraints") (the system's numpy)"
"$venv/bin/pip" install -q -c "$constraints" .

"$venv/bin/python" - "$system_site" <<'EOF'
import importlib, sys
system = sys.argv[1]
for name in ("numpy", "av"):
    module = importlib.import_module(name)
    if not module.__file__.startswith(system + "/"):
        sys.exit(f"{name} {module.__version__} is shadowed by {module.__file__}: the system's is in {system}")
    print(f"{name} {module.__version__} from {system} (the system's)")
EOF
if dpkg-query -W -f='${Status}' python3-picamera2 2>/dev/null | grep -q "ok installed"; then
    "$venv/bin/python" -c 'import picamera2; print("picamera2 imports")'
fi
echo "installed: $venv/bin/antiscatter"
