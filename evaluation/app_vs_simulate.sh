#!/usr/bin/env bash
# The probe app's physics against `voxelastic simulate` on the same scene and press (issue 25's
# "80 %"): simulate runs SCENE (its joystick plays the press from t = 0); the app runs SCENE with
# JOY (the same tilts after a wait) under a display and headless, --force-shaping local. The
# physics' pace is simulated seconds over wall seconds: simulate's after its start-up (its own
# summary line), the app's over the wall window [FROM, TO] s of its --force-log (`physics_s`
# against `wall_s`: the press). Same dt, so the ratio is the ratio of steps per second. The app
# never runs the tissue faster than real time, so where simulate is faster the ratio is to 1x.
#
#   evaluation/app_vs_simulate.sh [--repeat N] SCENE JOY FROM TO [OUT_DIR] [-- extra app and simulate options]
#   e.g. evaluation/app_vs_simulate.sh --repeat 3 folded-press-model.json samples/organ/folded-press.joy 60 70.5
#
# Run on a quiet machine. One round scatters: simulate's own pace read 0.59x to 0.80x on one
# machine in one day, and on two cores the display's share scatters the app's. --repeat N runs N
# rounds, each simulate, then the app with the display, then headless (the three side by side),
# prints every round, and gives the median of the rounds' shares (docs/probe.md "The app against
# simulate").
set -euo pipefail
usage() { echo "usage: $0 [--repeat N] SCENE JOY FROM_S TO_S [OUT_DIR] [-- extra options]" >&2; exit 2; }
rounds=1
if [ "${1:-}" = "--repeat" ]; then
  [ $# -ge 2 ] && [[ "$2" =~ ^[1-9][0-9]*$ ]] || { echo "$0: --repeat takes a whole number >= 1" >&2; exit 2; }
  rounds=$2
  shift 2
fi
[ $# -ge 4 ] || usage
scene=$1 joy=$2 from=$3 to=$4
shift 4
out=""
if [ $# -gt 0 ] && [ "$1" != "--" ]; then out=$1; shift; fi
[ $# -gt 0 ] && [ "$1" = "--" ] && shift
extra=("$@")
here=$(cd "$(dirname "$0")/.." && pwd)
bin=${VX_BUILD:-$here/build}/apps
for f in "$scene" "$joy"; do [ -f "$f" ] || { echo "$0: no such file: $f" >&2; exit 2; }; done
for b in "$bin/voxelastic/voxelastic" "$bin/probe/voxelastic-probe"; do
  [ -x "$b" ] || { echo "$0: $b is not built (scripts/build.sh, or set VX_BUILD)" >&2; exit 2; }
done
if [ -z "$out" ]; then out=$(mktemp -d /tmp/app-vs-simulate.XXXXXX); else mkdir -p "$out"; fi

# simulate: "start-up S s, ..." and "N steps, T s simulated in W s (...)"
simulate_pace() {  # the simulate log
  awk '/^start-up / {s = $2} / steps, .* s simulated in / {
    for (i = 1; i <= NF; ++i) { if ($i == "simulated") t = $(i - 2); if ($i == "in") w = $(i + 1) }
  } END { if (w - s > 0) printf "%.4f", t / (w - s) }' "$1"
}

# the app's pace over [from, to] from its force log (columns by name)
app_pace() {
  awk -F, -v a="$from" -v b="$to" 'NR == 1 { for (i = 1; i <= NF; ++i) c[$i] = i; next }
    { w = $c["wall_s"]; s = $c["physics_s"] }
    w >= a && !have { w0 = w; s0 = s; have = 1 }
    w <= b { w1 = w; s1 = s }
    END { if (have && w1 > w0) printf "%.4f", (s1 - s0) / (w1 - w0) }' "$1"
}
run_app() {  # name, then the launcher (may be empty)
  local name=$1
  shift
  "$@" "$bin/probe/voxelastic-probe" "$scene" --virtual-joystick "$joy" --exit-after-script --force-shaping local \
    --force-log "$dir/$name.csv" "${extra[@]}" "${app_extra[@]}" > "$dir/$name.log" 2>&1
  app_pace "$dir/$name.csv"
}

# The app paces its physics to the wall clock: it never runs the tissue faster than real time.
# So its figure is compared with what it can reach, simulate's pace up to 1x.
table=""
for ((round = 1; round <= rounds; ++round)); do
  dir=$out
  [ "$rounds" -gt 1 ] && dir=$out/round$round && mkdir -p "$dir"
  "$bin/voxelastic/voxelastic" simulate "$scene" --out "$dir/simulate" "${extra[@]}" > "$dir/simulate.log"
  sim=$(simulate_pace "$dir/simulate.log")
  [ -n "$sim" ] || { echo "$0: no summary line in $dir/simulate.log" >&2; exit 1; }
  app_extra=(--screenshot "$dir/display.png")
  display=$(run_app display "$here/scripts/with-display.sh")
  app_extra=(--headless)
  headless=$(run_app headless)
  [ -n "$display" ] && [ -n "$headless" ] || { echo "$0: no force log covers $from-$to s in $dir" >&2; exit 1; }
  [ "$rounds" -gt 1 ] && echo "round $round of $rounds: simulate ${sim}x, the app ${display}x with the display, ${headless}x headless"
  table+="$sim $display $headless"$'\n'
done

printf '%s' "$table" | awk -v a="$from" -v b="$to" -v n="$rounds" '
  function median(v, k,   i, j, t) {
    for (i = 2; i <= k; ++i) for (j = i; j > 1 && v[j - 1] > v[j]; --j) { t = v[j]; v[j] = v[j - 1]; v[j - 1] = t }
    return k % 2 ? v[(k + 1) / 2] : 0.5 * (v[k / 2] + v[k / 2 + 1])
  }
  { s[NR] = $1; r = $1 < 1 ? $1 : 1; d[NR] = $2; h[NR] = $3; ds[NR] = 100 * $2 / r; hs[NR] = 100 * $3 / r
    capped += $1 >= 1 }
  END {
    what = capped ? "real time or simulate, whichever is slower (the app'"'"'s ceiling is real time)" : "simulate"
    of = n > 1 ? sprintf(" (the median of %d rounds)", n) : ""
    printf "simulate after its start-up:      %.3fx real time%s\n", median(s, n), of
    printf "app with a display, %g-%g s wall: %.3fx real time: %.0f %% of %s%s\n", a, b, median(d, n), median(ds, n), what, of
    printf "app headless, the same window:    %.3fx real time: %.0f %% of %s%s\n", median(h, n), median(hs, n), what, of
  }'
echo "logs, force logs and the screenshot: $out"
