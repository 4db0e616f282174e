#!/usr/bin/env bash
# Rebuild every shipped artifact from its documented command (doc/howto/bag-library.md): the gain files
# config/gains/*.yaml, the identified plant config/systems/dc_motor_identified.yaml, and every
# library bag bags/<name>/ with its expected.yaml (bags/library.yaml).
#
#   scripts/regenerate.sh                    # everything, in place
#   scripts/regenerate.sh -o OUT             # into OUT (a copy of config/ and bags/ first)
#   scripts/regenerate.sh -o OUT f16xl_hinf_sc bags   # only these targets
#
# Targets: a gain file's name (config/gains/NAME.yaml; dc_motor_identified_thresholds also
# re-identifies its plant from three simulated bags), or `bags` (every library bag and its
# expected.yaml, made with the gain files of the tree written to). With -o, what is not
# regenerated is the shipped copy; shipped names resolve in OUT/config first
# (FD_MONITOR_CONFIG), so the bags are made with the regenerated gain files. Compare OUT with
# the shipped files within tolerance: python scripts/compare_regenerated.py OUT
# (test/test_regenerate.py does both). Runs .venv/bin/python (scripts/setup.sh makes it), or
# $PYTHON.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
out="$root"
targets=()
while [ $# -gt 0 ]; do
  case "$1" in
    -o) out="$2"; shift 2 ;;
    -h|--help) sed -n '2,/^[^#]/{/^#/p}' "$0"; exit 0 ;;
    *) targets+=("$1"); shift ;;
  esac
done
python="${PYTHON:-$root/.venv/bin/python}"
mkdir -p "$out"
out="$(cd "$out" && pwd)"
if [ "$out" != "$root" ]; then
  cp -r "$root/config" "$root/bags" "$out/"
fi
export FD_MONITOR_CONFIG="$out/config"
cd "$out"
gains=config/gains

want() {   # is target $1 asked for (no targets: all)?
  [ ${#targets[@]} -eq 0 ] && return 0
  local t
  for t in "${targets[@]}"; do [ "$t" = "$1" ] && return 0; done
  return 1
}
fdm() { "$python" -m fd_monitor "$@"; }
step() {   # step NAME: announce and remove the old file (a failed command leaves none)
  echo "regenerate: $1" >&2
  rm -f "$gains/$1.yaml"
}

# --- gain files ("Quadratic-boundedness observers", "QB at the samples")
if want pwa_cascade_qb; then
  step pwa_cascade_qb
  fdm design qb pwa_cascade -o $gains/pwa_cascade_qb.yaml --beta 0.486 > /dev/null
fi
if want pwa_cascade_qb_sampled; then
  step pwa_cascade_qb_sampled
  fdm design qb pwa_cascade --sampled -o $gains/pwa_cascade_qb_sampled.yaml > /dev/null
fi
# --- "H-infinity / H-minus residual generators": each from its design file
for plant in thesis_4_7 thesis_5_3 thesis_6_5 f16xl three_tank_lpv; do
  if want ${plant}_hinf_sc; then
    step ${plant}_hinf_sc
    fdm design hinf_sc $plant -o $gains/${plant}_hinf_sc.yaml > /dev/null
  fi
done
if want farhat_koenig_hminus_switched; then
  step farhat_koenig_hminus_switched
  fdm design hminus_switched farhat_koenig -o $gains/farhat_koenig_hminus_switched.yaml \
    > /dev/null
fi
# --- "Sensor-bias diagnosis chain": scenario design (~10 s) and declared envelope (~9 s)
if want three_tank_thresholds; then
  step three_tank_thresholds
  fdm design thresholds three_tank -o $gains/three_tank_thresholds.yaml > /dev/null
fi
if want three_tank_envelope; then
  step three_tank_envelope
  fdm design thresholds three_tank --envelope declared -o $gains/three_tank_envelope.yaml \
    > /dev/null
fi
# --- "Monitor your own robot": bags of the simulated motor -> identify -> design
if want dc_motor_identified_thresholds; then
  step dc_motor_identified_thresholds
  work="$(mktemp -d)"
  trap 'rm -rf "$work"' EXIT
  mkdir "$work/motor"
  # relative bag names: identify records them in the plant file's header
  (cd "$work"
   for i in 1 2 3; do
     fdm simulate dc_motor_nominal --seed $i --adapter dc_motor -o motor/run$i > /dev/null
   done
   fdm identify motor/run1 motor/run2 --holdout motor/run3 --adapter dc_motor \
     --name dc_motor_identified -o "$out/config/systems/dc_motor_identified.yaml" \
     --force > /dev/null)
  fdm design thresholds dc_motor_identified --envelope declared \
    -o $gains/dc_motor_identified_thresholds.yaml > /dev/null
fi
# --- "Bag library": every bag and its expected.yaml, with the gain files above
if want bags; then
  echo "regenerate: bags" >&2
  fdm simulate --library bags/library.yaml --expected > /dev/null
fi
echo "regenerate: done ($out)" >&2
