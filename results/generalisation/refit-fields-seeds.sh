#!/bin/sh
# The refit of results/generalisation/refit-fields.sh for seeds 1 and 2 (the rule's three refit seeds with seed 0).
set -e
for seed in 1 2; do
    /usr/bin/time -v results/generalisation/refit-fields.sh $seed 100 80 > results/generalisation/refit-fields-s$seed.log 2>&1
done
