#!/usr/bin/env bash
# Screenshots of a compare and a diagnose report into docs/images/ (headless Chromium).
# Makes a short synthetic run (two 0.1 s forte trials, a compliant string hidden in it),
# compares the string model with it, diagnoses the base model, and screenshots the top
# of each report at 1200x1800 px; the PNGs are quantized to 64 colours to stay small.
# Usage: bash tools/screenshots.sh   (from the repository; python: $PYTHON or .venv)
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-.venv/bin/python}
CHROMIUM=$(command -v chromium || command -v chromium-browser)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
printf 'effects: [{compliant_string: {stiffness: 20000}}]\n' > "$work/truth.yaml"
printf 'effects: [compliant_string]\n' > "$work/string.yaml"
"$PY" -m rig synth --model "$work/truth.yaml" --profile profiles/forte.yaml --out "$work/run.h5" \
    --seed 5 --duration 0.1 --trials 2 --no-load-cell-filter
"$PY" -m rig compare "$work/run.h5" --model "$work/string.yaml" --trial 0 --trial 1 \
    --report "$work/compare.html" > /dev/null
"$PY" -m rig diagnose "$work/run.h5" --candidate compliant_string --candidate load_cell_filter \
    --jobs 1 --report "$work/diagnose.html" > /dev/null
mkdir -p docs/images
for name in compare diagnose; do
    "$CHROMIUM" --headless --no-sandbox --disable-gpu --disable-dev-shm-usage --hide-scrollbars \
        --virtual-time-budget=10000 --window-size=1200,1800 \
        --screenshot="$work/$name.png" "file://$work/$name.html" 2> /dev/null
    "$PY" - "$work/$name.png" "docs/images/report-$name.png" <<'PYEOF'
import sys
from PIL import Image
Image.open(sys.argv[1]).convert("RGB").quantize(colors=64).save(sys.argv[2], optimize=True)
PYEOF
    echo "wrote docs/images/report-$name.png"
done
