# Sourced by .ci/run and scripts/test.sh: `stage TEXT` starts a stage. It
# prints the seconds since the script started and, for the stage it ends,
# its length and how busy the machine's CPUs were over it (from /proc/stat):
# where CI's time goes, and whether a stage left cores idle that another
# could use (docs/design/testing.md#where-cis-time-goes).
#
#   == [193s] tests (README command, all features)
#      (the stage before: 185 s, CPU 71 % busy + 22 % at idle priority)
#
# "At idle priority" is niced work (the fuzz build CI runs in the
# background), counted apart: it yields to every other stage.

# The CPU counters of /proc/stat's first line: busy (user, system, irq,
# softirq, steal), niced and total jiffies. Empty where there is no /proc.
_stage_cpu() {
  [ -r /proc/stat ] || return 0
  awk '/^cpu / { busy = $2 + $4 + $7 + $8 + $9; nice = $3;
                 total = busy + nice + $5 + $6; print busy, nice, total; exit }' /proc/stat
}

_stage_start=
_stage_cpu_start=
stage() {
  local now=$SECONDS cpu
  cpu=$(_stage_cpu)
  if [ -n "$_stage_start" ]; then
    local len=$((now - _stage_start)) usage=""
    if [ -n "$cpu" ] && [ -n "$_stage_cpu_start" ]; then
      usage=$(awk -v a="$_stage_cpu_start" -v b="$cpu" 'BEGIN {
        split(a, x, " "); split(b, y, " "); t = y[3] - x[3];
        if (t > 0) printf ", CPU %d %% busy + %d %% at idle priority",
          100 * (y[1] - x[1]) / t, 100 * (y[2] - x[2]) / t }')
    fi
    echo "   (the stage before: ${len} s${usage})"
  fi
  echo "== [${now}s] $*"
  _stage_start=$now
  _stage_cpu_start=$cpu
}
