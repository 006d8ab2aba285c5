#!/bin/bash
# Our RRTConnect with the outside victims' goal list (K = 32, --goal-list) on the solvable M = 10 attacks.
for s in table_pick table_under_pick bookshelf box cage; do
  advocc evaluate --scene $s --obstacles /work/bench_runs/a1_transfer_solvable/attacks/$s/task_b10_v0.yaml \
    --planner rrtconnect --goal-list --trials 20 --workers 2 --json > /work/bench_runs/a1_goal_list/$s.json
done
