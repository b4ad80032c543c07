#!/usr/bin/env bash
# Exact reference policies (ham baselines) on tables of the next world, made for #12 after the
# bowl became shallow: curvature2d (x,y) 21^2 again; composite:train with tilts, (x,y,phi) 21^3
# and (x,y,phi,phi_y) 9^4 (the (x,y) 21^2 composite table is in run.sh). Each table's outputs are
# gathered into baselines_<set>_<dims>_<grid>.json keyed "policy|height=True|tol=T".
set -euo pipefail
OUT=${OUT:-runs/next_world_tables}; mkdir -p "$OUT"; cd "$OUT"
HAM=${HAM:-ham}
PY=${PY:-python3}
while read -r objects dims grid; do
  name="${objects/:/-}_${dims//,/}_$grid"
  [ -f "$name.h5" ] || $HAM table build --objects "$objects" --pose-dims "$dims" --grid "$grid" \
    --out "$name.h5" --quiet
  parts=()
  for tolerance in 1e-6 0.2; do
    for policy in random infogain oracle; do
      first=(); [ $policy = random ] || first=(--first random)
      part="$name.$policy.$tolerance.json"
      $HAM baselines --policy $policy --table "$name.h5" --glances 1 2 3 4 5 6 "${first[@]}" \
        --height --tolerance $tolerance --json > "$part"
      parts+=("$part")
    done
  done
  $PY - "baselines_$name.json" "${parts[@]}" <<'PYEOF'
import json, os, sys
out, merged = sys.argv[1], {}
for path in sys.argv[2:]:
    d = json.load(open(path))
    merged[f"{d['policy']}|height={d['height']}|tol={d['tolerance']:g}"] = d
with open(out + ".tmp", "w") as f:
    json.dump(merged, f, indent=1)
os.replace(out + ".tmp", out)
PYEOF
done <<'LIST'
curvature2d x,y 21
composite:train x,y,phi 21
composite:train x,y,phi,phi_y 9
LIST
echo ALLDONE
