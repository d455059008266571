#!/usr/bin/env bash
# Run ArduPlane SITL with its SERIAL1 MAVLink 2 link sent to the mavservo bridge.
#
#   mavservo sitl arduplane [--gimbal] [--port 14551] [--host 127.0.0.1] [--speedup 1]
#                           [--wait-gcs] [--no-wipe] [--dry-run] [-- extra args for arduplane]
#   (this script, from the installed package; run-arduplane.sh takes the same options)
#
# Runs the arduplane binary that is already built: $ARDUPILOT_HOME/build/sitl/bin/arduplane,
# else arduplane on PATH, else the build/sitl/bin/arduplane of the tree whose Tools/autotest
# holds the sim_vehicle.py on PATH. It never runs sim_vehicle.py: that script reconfigures the
# tree, rebuilds it and may fetch submodules. The autotest plane defaults
# (Tools/autotest/models/plane.parm; default_params/plane.parm in older trees) come from that
# tree. SERIAL0 listens on TCP 5760 + 10 x instance for a GCS without waiting for one (--wait-gcs:
# SITL's own default, which boots only once a client connects and ignores SIGTERM until then);
# SIGTERM stops it cleanly. It reads nothing from its standard input, so it runs in the
# background. Never downloads or builds anything: when no built binary is found it says so and
# exits with status 3. --dry-run prints the command instead of running it (status 0); without a
# binary that is the command to use once it is built, with a note on stderr that it is not.
# Then run the bridge with:  mavservo run --config DIR/ardupilot-sitl.yaml  (mavservo examples DIR)
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
port=14551
host=127.0.0.1
speedup=1
gimbal=0
wipe=1
wait_gcs=0
dry_run=0
extra=()

while [[ $# -gt 0 ]]; do
  case "$1" in
    --gimbal) gimbal=1 ;;
    --port) port="$2"; shift ;;
    --host) host="$2"; shift ;;
    --speedup) speedup="$2"; shift ;;
    --no-wipe) wipe=0 ;;
    --wait-gcs) wait_gcs=1 ;;
    --dry-run) dry_run=1 ;;
    --) shift; extra=("$@"); break ;;
    -h|--help) sed -n '2,/^[^#]/{/^#/{s/^# \{0,1\}//;p;};}' "$0"; exit 0 ;;
    *) echo "run-arduplane.sh: unknown option $1 (try --help)" >&2; exit 2 ;;
  esac
  shift
done

parms=("$here/arduplane-companion.parm")
if [[ $gimbal -eq 1 ]]; then
  parms+=("$here/arduplane-gimbal.parm")
fi
serial1="udpclient:${host}:${port}"

binary=""
tree=""
if command -v arduplane >/dev/null 2>&1; then
  binary="$(command -v arduplane)"
fi
if [[ -z "$binary" ]] && command -v sim_vehicle.py >/dev/null 2>&1; then
  # sim_vehicle.py lives in TREE/Tools/autotest: use that tree's build, never the script
  tree="$(cd "$(dirname "$(command -v sim_vehicle.py)")/../.." && pwd)"
  if [[ -x "$tree/build/sitl/bin/arduplane" ]]; then
    binary="$tree/build/sitl/bin/arduplane"
  fi
fi
if [[ -n "${ARDUPILOT_HOME:-}" && -x "${ARDUPILOT_HOME}/build/sitl/bin/arduplane" ]]; then
  binary="${ARDUPILOT_HOME}/build/sitl/bin/arduplane"  # an explicit tree wins over PATH
fi

# The autotest plane defaults of the tree the binary belongs to (models/ today, default_params/
# before ArduPilot moved them).
plane_defaults() {
  local home="${ARDUPILOT_HOME:-}"
  if [[ -z "$home" && "$binary" == */build/sitl/bin/arduplane ]]; then
    home="${binary%/build/sitl/bin/arduplane}"
  fi
  if [[ -z "$home" ]]; then home="$tree"; fi
  [[ -n "$home" ]] || return 0
  for candidate in Tools/autotest/models/plane.parm Tools/autotest/default_params/plane.parm; do
    if [[ -f "$home/$candidate" ]]; then
      echo "$home/$candidate"
      return 0
    fi
  done
}

binary_cmd() {
  local program="$1" defaults
  defaults="$(plane_defaults)"
  if [[ -n "$defaults" ]]; then
    defaults+=","
  elif [[ $dry_run -eq 0 ]]; then
    echo "run-arduplane.sh: no Tools/autotest/models/plane.parm found (set ARDUPILOT_HOME to the" \
      "ArduPilot tree); SITL starts without the autotest plane defaults" >&2
  fi
  defaults+="$(IFS=,; echo "${parms[*]}")"
  serial0="tcp:0"  # SERIAL0 for a GCS, on 5760; ":wait" would hold the boot until one connects
  if [[ $wait_gcs -eq 1 ]]; then serial0="tcp:0:wait"; fi
  cmd=("$program" --model plane --speedup "$speedup" --defaults "$defaults"
       --serial0 "$serial0" --serial1 "$serial1" -I0)
  if [[ $wipe -eq 1 ]]; then cmd+=(-w); fi
}

if [[ -n "$binary" ]]; then
  binary_cmd "$binary"
elif [[ $dry_run -eq 1 ]]; then
  # show what to run once ArduPilot is built, and say it is not yet
  binary_cmd "${ARDUPILOT_HOME:-${tree:-ARDUPILOT_HOME}}/build/sitl/bin/arduplane"
  echo "run-arduplane.sh: ArduPilot SITL is not built here; once it is (see docs/engineering/sitl.md)," \
    "this is the command:" >&2
else
  where="neither arduplane on PATH nor \$ARDUPILOT_HOME/build/sitl/bin/arduplane"
  if [[ -n "$tree" ]]; then where="no build/sitl/bin/arduplane in $tree (sim_vehicle.py's tree)"; fi
  cat >&2 <<MSG
run-arduplane.sh: ArduPilot SITL is not built: $where.
Build it yourself, once, for example:
  git clone --recursive https://github.com/ArduPilot/ardupilot && cd ardupilot
  Tools/environment_install/install-prereqs-ubuntu.sh -y && ./waf configure --board sitl && ./waf plane
then set ARDUPILOT_HOME to the tree (or put Tools/autotest, or build/sitl/bin, on PATH).
This script never downloads nor builds anything, and never runs sim_vehicle.py. See docs/engineering/sitl.md.
MSG
  exit 3
fi
cmd+=("${extra[@]}")

if [[ $dry_run -eq 1 ]]; then
  printf '%q ' "${cmd[@]}"
  echo
  exit 0
fi
echo "run-arduplane.sh: SERIAL1 -> ${serial1} (bridge: mavlink.url udpin:${host}:${port})" >&2
exec "${cmd[@]}" < /dev/null
