#!/usr/bin/env bash
# Paper scale (issue #29): one `hykin fit` on N simulated samples (the paper's Table I goes to 400,000),
# with its wall time and peak memory (GNU time's "Maximum resident set size"), then its test errors.
#
#   bash benchmarks/paper_scale.sh [N=400000] [MAX_MINUTES=60] [THREADS=2]
#
# Data: rx160-virtual (tracker-like noise), N training samples (seed 0) and 20,000 test samples (seed 1),
# simulated into a temp dir (kept; its path is printed). The fit is hykin's default (calibration +
# default networks and recipe) with --max-minutes MAX_MINUTES as the training budget, THREADS torch /
# numba threads. Prints one line: N, fit wall s, peak RSS MiB, CPU s, test errors.
# Needs GNU time at /usr/bin/time; `python` must run hykin (e.g. PYTHONPATH=. /path/to/venv/bin/python).
set -euo pipefail
N=${1:-400000}
MAXMIN=${2:-60}
THREADS=${3:-2}
PY=${PYTHON:-python}
export OMP_NUM_THREADS=$THREADS MKL_NUM_THREADS=$THREADS NUMBA_NUM_THREADS=$THREADS
D=$(mktemp -d /tmp/hykin-paper-scale-XXXX)
echo "data and logs in $D"
SECONDS=0
$PY -m hykin simulate rx160-virtual -n "$N" --seed 0 -o "$D/train.csv" > /dev/null
$PY -m hykin simulate rx160-virtual -n 20000 --seed 1 -o "$D/test.csv" > /dev/null
echo "simulated in ${SECONDS} s"
/usr/bin/time -v -o "$D/time.txt" $PY -m hykin fit rx160 "$D/train.csv" -o "$D/model.hykin" \
    --max-minutes "$MAXMIN" --seed 0 --force > "$D/fit.log" 2>&1 || { tail -20 "$D/fit.log"; exit 1; }
$PY -m hykin evaluate "$D/model.hykin" "$D/test.csv" > "$D/evaluate.txt" 2>&1 || true
wall=$(grep "Elapsed (wall clock)" "$D/time.txt" | awk '{print $NF}')
rss=$(grep "Maximum resident set size" "$D/time.txt" | awk '{printf "%.0f", $NF / 1024}')
cpu=$(awk -F': ' '/User time|System time/ {s += $2} END {printf "%.0f", s}' "$D/time.txt")
echo "N=$N fit wall (h:mm:ss or m:ss) $wall, peak RSS $rss MiB, CPU $cpu s (threads $THREADS, max-minutes $MAXMIN)"
tail -3 "$D/fit.log"
cat "$D/evaluate.txt"
