#!/bin/bash
# Session rglexp driver (benchmarks/studies/neubrdf/results/neubrdf_rgl_defaults.md); paths under /tmp/rglexp as run.
# usage: run_arm.sh TAG SRC [--set ...]   -> /tmp/rglexp/TAG.nmat, TAG.fit.log, TAG.eval.json (eval in the background)
TAG=$1; SRC=$2; shift 2
cd /work/wtexp
export PYTHONPATH=/work/wtexp/src OMP_NUM_THREADS=1
PY=/work/wtexp/.venv/bin/python
t0=$(date +%s.%N)
nice -n 10 $PY -m neumat fit "$SRC" --model neubrdf --recipe cpu --threads 1 -q "$@" -o /tmp/rglexp/$TAG.nmat > /tmp/rglexp/$TAG.fit.log 2>&1
rc=$?
t1=$(date +%s.%N)
echo "{\"tag\": \"$TAG\", \"src\": \"$SRC\", \"args\": \"$*\", \"rc\": $rc, \"fit_s\": $(echo "$t1 - $t0" | bc)}" > /tmp/rglexp/$TAG.meta.json
(
nice -n 10 $PY -m neumat eval /tmp/rglexp/$TAG.nmat --against "$SRC" --json --spp 512 --resolution 128 --n-configs 65536 > /tmp/rglexp/$TAG.eval.json 2> /tmp/rglexp/$TAG.eval.err
t2=$(date +%s.%N)
echo "$TAG done fit $(echo "$t1 - $t0" | bc) s eval $(echo "$t2 - $t1" | bc) s rc=$rc" >> /tmp/rglexp/progress.log
) &
