#!/usr/bin/env bash
# Install everything into VENV: pinned wheels, the OMPL fix-up, advocc_msgs, advocc_ros.
# Idempotent; nothing is written outside the repository.
set -euo pipefail
venv=${1:-.venv}
here=$(cd "$(dirname "$0")/.." && pwd)
py="$venv/bin/python"

"$py" -m pip install --quiet --disable-pip-version-check -e "$here[build,test]"

# ompl 1.7.0's wheel ships a second, un-renamed libompl next to the one its extensions link;
# ompl/__init__.py loads it with ctypes, so OMPL's statics are destroyed twice and every
# interpreter segfaults at exit. Remove the stray copies (the extensions keep theirs).
site=$("$py" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
rm -f "$site"/libompl.so "$site"/libompl.so.*

"$here/tools/build_msgs.sh" "$venv" "$here/build/advocc_msgs"
"$py" -c 'import advocc_msgs.srv, rclpy, pinocchio, coal, ompl.geometric' \
  || { echo "install check failed: see messages above" >&2; exit 1; }
echo "advocc_ros installed in $venv"
