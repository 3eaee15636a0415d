#!/usr/bin/env bash
# How much two of the workflow's jobs slow each other on a 2-core machine (each at one thread, as the
# workflow runs them): the SASA training step (benchmarks/sasa.py, DEFAULTS, on results/scenes) alone,
# beside a second training, beside an `ours` detection and beside a `paper` detection
# (benchmarks/detect.py on the dev scenes), and each detection alone. If one pair slowed much more
# than the others, the scheduler could keep it apart; otherwise the run time is the job time over
# the cores, whatever runs beside what.
#
# Usage, from the root of a checkout that holds a default run's results/:
#   bash benchmarks/corun.sh [STEPS]      (default 40 timed training steps)
# Takes about 5 min; run it on an otherwise idle machine.
set -euo pipefail
steps=${1:-40}
py=${PYTHON:-.venv/bin/python}
if [ ! -d results/scenes ] || [ ! -f results/splits/dev.txt ]; then
    echo "corun: results/scenes or results/splits/dev.txt is missing; run the workflow first" \
         "(snakemake --cores 2)" >&2
    exit 2
fi
eval "$($py -m sonardet.determinism)"
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
sasa() {  # "median X fastest Y s/step" of one DEFAULTS training at one thread
    $py benchmarks/sasa.py --threads 1 --configs DEFAULTS --steps "$steps" --warmup 3 2>/dev/null \
        | awk -F'|' '/^DEFAULTS/ {gsub(/ /, "", $6); gsub(/ /, "", $7); print "median", $6, "fastest", $7, "s/step"}'
}
detect() {  # detect VARIANT SCENES REPEAT: "X s per scene (max Y)" of the first pass
    $py benchmarks/detect.py --scenes "$2" --variants "$1" --threads 1 --repeat "$3" --no-skip-compare 2>&1 \
        | grep -o "[0-9.]* s per scene (max [0-9.]*)" | head -1
}
echo "load before: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "SASA alone:               $(sasa)"
sasa > "$tmp/a" & sasa > "$tmp/b"; wait
echo "SASA beside SASA:         $(cat "$tmp/a") | $(cat "$tmp/b")"
detect ours 0 2 > /dev/null & sleep 3; echo "SASA beside ours:         $(sasa)"; wait
detect paper 6 1 > /dev/null & sleep 3; echo "SASA beside paper:        $(sasa)"; wait
sasa > /dev/null & echo "ours beside SASA:         $(detect ours 0 1) (SASA beside it for its first part)"; wait
echo "ours alone:               $(detect ours 0 1)"
echo "paper alone (6 scenes):   $(detect paper 6 1)"
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
