#!/usr/bin/env bash
# Fingerprints of what the CPU backend computes, to show that a change
# meant to move code (not physics) leaves every result bitwise as it was.
#
#   tests/support/bitwise.sh EIKON OUT/      # run every case, write OUT/sums.txt
#   diff OUT_before/sums.txt OUT_after/sums.txt
#
# EIKON is an eikon binary (e.g. target/release/eikon). Every config is
# simulated (wavefront and photons, both deposit rules), rendered (eikonal,
# and the exact mesh methods where the scene is a mesh), traced, sliced and
# exported as .npy, at small sizes so the whole run takes a few minutes on two
# cores. Only array and image bytes are hashed: sidecars carry run ids and
# timings.
set -euo pipefail
eikon=$(realpath "$1")
out=$2
here=$(cd "$(dirname "$0")/../.." && pwd)
rm -rf "$out"
mkdir -p "$out"
out=$(realpath "$out")
cd "$here"
res=14
size=(--width 40 --height 30 --samples 2)
sums="$out/sums.txt"
: >"$sums"
run() { # command...: quiet, but say what failed
  if ! "$@" >"$out/last.log" 2>&1; then
    echo "failed: $*" >&2
    cat "$out/last.log" >&2
    exit 1
  fi
}
hash() { # label files...
  local label=$1
  shift
  for f in "$@"; do
    printf '%s %s %s\n' "$label" "$(basename "$f")" "$(sha256sum "$f" | cut -d' ' -f1)" >>"$sums"
  done
}
for cfg in configs/*.toml; do
  name=$(basename "$cfg" .toml)
  [ "$name" = orbit ] && continue # animated: covered by the frame tests
  d="$out/$name"
  mkdir -p "$d"
  run "$eikon" simulate "$cfg" --resolution $res --backend cpu -o "$d/light"
  hash "$name/simulate" "$d"/light/*.npy
  run "$eikon" render "$cfg" --resolution $res --backend cpu --light "$d/light" "${size[@]}" \
    -o "$d/eikonal.exr" -o "$d/eikonal.png"
  hash "$name/render" "$d/eikonal.exr" "$d/eikonal.png"
  run "$eikon" render "$cfg" --resolution $res --backend cpu --light "$d/light" "${size[@]}" \
    --integrator rk4 --no-skip -o "$d/rk4.exr"
  hash "$name/render-rk4" "$d/rk4.exr"
  run "$eikon" slice "$cfg" --axis y --at 0.5 -o "$d/slice.png"
  hash "$name/slice" "$d/slice.png"
  run "$eikon" export "$cfg" --resolution $res --light "$d/light" --npy "$d/npy" --vdb "$d/volumes.vdb"
  hash "$name/export" "$d"/npy/*.npy "$d/volumes.vdb"
  if grep -q 'type *= *"\(mesh\|bumpy_sphere\|cuboctahedron\)"' "$cfg"; then
    for m in walter holzschuch straight; do
      run "$eikon" render "$cfg" --method $m --width 24 --height 18 --samples 1 \
        -o "$d/$m.exr"
      hash "$name/$m" "$d/$m.exr"
    done
  fi
done
# Both deposit rules, Fresnel off, the photon baseline and RK4 light.
cfg=configs/glass-sphere.toml
d="$out/glass-sphere-variants"
mkdir -p "$d"
run "$eikon" simulate $cfg --resolution 20 --backend cpu --deposit paper --no-fresnel -o "$d/paper"
hash variants/paper "$d"/paper/*.npy
run "$eikon" simulate $cfg --resolution 20 --backend cpu --method photons --count 20000 -o "$d/photons"
hash variants/photons "$d"/photons/*.npy
run "$eikon" simulate $cfg --resolution 20 --backend cpu --integrator rk4 -o "$d/rk4"
hash variants/rk4 "$d"/rk4/*.npy
# One traced ray per integrator and form, printed in full.
for integ in euler rk4 dopri5; do
  for form in distance time; do
    "$eikon" trace configs/luneburg.toml --origin -2,0.3,0.1 --dir 1,0,0 \
      --integrator $integ --form $form --json >"$d/trace-$integ-$form.json" 2>/dev/null
    hash trace/$integ-$form "$d/trace-$integ-$form.json"
  done
done
sort -o "$sums" "$sums"
wc -l <"$sums"
