# usage: bash item3_queue.sh NAME   (issue 32 item 3: Fig. 4 at 400-300 and Table 1 at 64-64, as registered in the study
# README; its run log says how the sessions use it). Takes the jobs of $Q/jobs.txt ("ID|reproduce.py arguments", written
# by `bash item3_jobs.sh > $Q/jobs.txt`) in order, one at a time: a job is skipped when it is done ($Q/done/ID), failed
# ($Q/failed/ID: look, then delete to retry) or claimed by a live runner ($Q/claims/ID holds its pid); a job killed by a
# signal stays open. Run one per core. Each job resumes from its runs' checkpoints under $WORK; runs are filed under $OUT.
# Settings (environment): VENV, STUDY (the study folder of the worktree the runs use), Q, WORK, OUT; RUN replaces the
# command (for a dry test).
source "${VENV:-/work/venv}/bin/activate"
cd "${STUDY:-/work/item3/experiments/macb_paper}" || exit 1
Q=${Q:-/work/i3queue}; WORK=${WORK:-/work/i3ckpt}; OUT=${OUT:-/work/i3res}; RUN=${RUN:-python scripts/reproduce.py}
me=${1:-runner}
mkdir -p "$Q/claims" "$Q/done" "$Q/failed"
while true; do
  job=""; jobargs=""
  exec 9>"$Q/.lock"; flock 9
  while IFS='|' read -r id args; do
    [ -z "$id" ] && continue
    [ -e "$Q/done/$id" ] || [ -e "$Q/failed/$id" ] && continue
    if [ -f "$Q/claims/$id" ]; then
      pid=$(cat "$Q/claims/$id")
      if kill -0 "$pid" 2>/dev/null && grep -q item3_queue "/proc/$pid/cmdline" 2>/dev/null; then continue; fi
    fi
    echo $$ > "$Q/claims/$id"; job=$id; jobargs=$args; break
  done < "$Q/jobs.txt"
  flock -u 9; exec 9>&-
  if [ -z "$job" ]; then echo "$(date +%F\ %T) $me: nothing left to take"; break; fi
  echo "$(date +%F\ %T) $me: starts $job"
  if $RUN $jobargs --work "$WORK" -o "$OUT"; then
    touch "$Q/done/$job"; echo "$(date +%F\ %T) $me: $job done"
  else
    rc=$?
    if [ $rc -ge 128 ]; then  # killed by a signal (the end of a session): the job stays open for the next runner
      echo "$(date +%F\ %T) $me: $job killed (rc $rc)"; rm -f "$Q/claims/$job"; break
    fi
    echo "rc $rc at $(date +%F\ %T)" > "$Q/failed/$job"; echo "$(date +%F\ %T) $me: $job FAILED (rc $rc)"
  fi
  rm -f "$Q/claims/$job"
done
