#!/usr/bin/env bash
# Runs the issues' CPU benches on the device machine from a scripts/device_bundle.sh bundle,
# one log per part under $OUT; with bin-before/ in the bundle every round runs before, then
# after (interleaved: both sides of a ratio on one machine, in one call).
#   OUT=dir bash device_run.sh PART...
# Parts (rounds: CLASTRACE_DEVICE_ROUNDS, default 7; passes inside one cluster bench run:
# CLASTRACE_DEVICE_REPEAT, default 3, best of them):
#   trav        bench_engine_nv --traversal 100000 3 (engine / Embree MEDIUM), per round
#   clusters    bench_engine_clusters thread sweep on WusonOBJ, per sweep round
#               (CLASTRACE_DEVICE_SWEEPS, default 3: one sweep a side cannot rank on a noisy VM)
#   clusters1   the same at 1 thread, per round
#   clusters-measures  the after side's bench, one process: counts 1 and 16, 3 sweeps in each of
#               its measure and session 16's (--both-measures), alternating (about 100 s)
#   replay      replay_throughput_bench --replay-once, 1 thread, hazards on and off, per round
#   replay16    the same at 16 threads, hazards on, per round, then peak RSS per side
#   cap         capture_overhead_bench 360 256 3 host-writes on the NVIDIA driver, per round
#               (CLASTRACE_DEVICE_CAP_ROUNDS, default 3), sides interleaved round by round; the
#               after side's bench drives both sides' layer and frames app (one measure)
#   cap-stats   the frames app, 240 frames, serving only then capturing, with the layer's stats
#   prof-trav prof-clus prof-rep1 prof-rep16 prof-cap   perf cpu-clock profiles of the after
#               side (bundle made with --perf; the VM has no hardware counters)
#   prof-build  the cluster build alone (--engine-only, WusonOBJ, 300 builds), by symbol, and
#               the hottest instructions of build_bvh and encode_object (their whole
#               annotations in $OUT/annotate_*.txt); profiles the before side too when present
set -uo pipefail
here=$(cd "$(dirname "$0")" && pwd)
export LD_LIBRARY_PATH=$here/lib
: "${OUT:?set OUT to the folder for the logs}"
rounds=${CLASTRACE_DEVICE_ROUNDS:-7}
repeat=${CLASTRACE_DEVICE_REPEAT:-3}
sweeps=${CLASTRACE_DEVICE_SWEEPS:-3}
cap_rounds=${CLASTRACE_DEVICE_CAP_ROUNDS:-3}
sides=(after); [[ -d $here/bin-before ]] && sides=(before after)
trace=/dev/shm/clastrace_device_replay.clt
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
mkdir -p "$OUT"
if [[ -d $here/debs ]]; then for deb in "$here"/debs/*.deb; do dpkg -x "$deb" /; done; ldconfig; fi

bin() { echo "$here/bin-$1/$2"; }
replay_trace() { [[ -f $trace ]] || "$(bin after replay_throughput_bench)" --write-trace "$trace" 300000; }
perf_report() { "$(bin after perf)" report -i "$1" --stdio --no-children --sort "$2" --percent-limit 0.4 2>&1 | grep '%' | head -150; }
profile() { # profile NAME COMMAND...: cpu-clock samples of the after side, report by symbol
  local data=/dev/shm/clastrace_$1.data; shift
  "$(bin after perf)" record -q -e cpu-clock -F 1999 -o "$data" -- "$@"
  perf_report "$data" dso,sym
}

run_part() {
  local part=$1 r side
  case $part in
    trav) for r in $(seq "$rounds"); do for side in "${sides[@]}"; do echo "-- round $r $side"
            "$(bin "$side" bench_engine_nv)" --traversal 100000 3 2>&1 | grep -E '^(icosphere|terrain|soup|torus)'; done; done ;;
    clusters) for r in $(seq "$sweeps"); do for side in "${sides[@]}"; do echo "-- sweep $r $side"
            "$(bin "$side" bench_engine_clusters)" --throughput-only --repeat "$repeat" --mesh "$here/WusonOBJ.obj"; done; done ;;
    clusters1) for r in $(seq "$rounds"); do for side in "${sides[@]}"; do echo "-- round $r $side"
            "$(bin "$side" bench_engine_clusters)" --throughput-only --max-threads 1 --repeat "$repeat" \
              --mesh "$here/WusonOBJ.obj" 2>&1 | grep -E '^build throughput|^ +1 +(wall|cpu)'; done; done ;;
    clusters-measures) "$(bin after bench_engine_clusters)" --builds-only --repeat "$repeat" --counts 16 \
              --sweeps "$sweeps" --both-measures --mesh "$here/WusonOBJ.obj" ;;
    replay) replay_trace; for r in $(seq "$rounds"); do for side in "${sides[@]}"; do for m in hazards no-hazards; do
            echo "-- round $r $side $m 1"; "$(bin "$side" replay_throughput_bench)" --replay-once "$trace" $m 1; done; done; done ;;
    replay16) replay_trace; for r in $(seq "$rounds"); do for side in "${sides[@]}"; do echo "-- round $r $side 16"
            "$(bin "$side" replay_throughput_bench)" --replay-once "$trace" hazards 16; done; done
          for side in "${sides[@]}"; do echo "-- rss $side 16"
            /usr/bin/time -v "$(bin "$side" replay_throughput_bench)" --replay-once "$trace" hazards 16 2>&1 |
              grep -E 'ops, hazards|Maximum resident'; done ;;
    cap) for r in $(seq "$cap_rounds"); do for side in "${sides[@]}"; do echo "-- round $r $side"
            ( cd /tmp && CLASTRACE_BENCH_DRIVER_FILES=$icd CLASTRACE_BENCH_LAYER_DIR=$here/layer-$side \
              CLASTRACE_BENCH_FRAMES_APP=$(bin "$side" capture_frames_app) \
              taskset -c 2-5 "$(bin after capture_overhead_bench)" 360 256 3 host-writes ); done; done ;;
    cap-stats) for side in "${sides[@]}"; do for mode in CLASTRACE_CAPTURE=0 CLASTRACE_OUTPUT=/dev/shm/c.clt; do
            echo "-- $side $mode"; env "$mode" VK_ICD_FILENAMES=$icd VK_DRIVER_FILES=$icd VK_ADD_LAYER_PATH=$here/layer-$side \
              VK_INSTANCE_LAYERS=VK_LAYER_CLASTRACE_capture CLASTRACE_STATS=1 \
              taskset -c 2-5 "$(bin "$side" capture_frames_app)" frames 240 --clusters 256; done; done ;;
    prof-trav) profile trav taskset -c 3 "$(bin after bench_engine_nv)" --traversal 100000 1 ;;
    prof-clus) profile clus taskset -c 3 "$(bin after bench_engine_clusters)" --throughput-only \
                 --max-threads 1 --repeat 3 --mesh "$here/WusonOBJ.obj" ;;
    prof-build) for side in "${sides[@]}"; do echo "-- $side"
            local data=/dev/shm/clastrace_build_$side.data
            "$(bin after perf)" record -q -e cpu-clock -F 1999 -o "$data" -- taskset -c 3 \
              "$(bin "$side" bench_engine_clusters)" --engine-only --repeat 300 --scene WusonOBJ \
              --mesh "$here/WusonOBJ.obj" 2>&1 | grep 'engine build'
            perf_report "$data" dso,sym
            for f in build_bvh encode_object; do
              "$(bin after perf)" annotate -i "$data" --stdio "clastrace::engine::detail::$f" \
                > "$OUT/annotate_${f}_$side.txt" 2>&1
              echo "-- hottest instructions of $f ($side)"
              grep -E '^ +[0-9]+\.[0-9]+ +:' "$OUT/annotate_${f}_$side.txt" | sort -rn | sed -n 1,40p; done; done ;;
    prof-rep1) replay_trace; profile rep1 taskset -c 3 "$(bin after replay_throughput_bench)" --replay-once "$trace" hazards 1 ;;
    prof-rep16) replay_trace; profile rep16 "$(bin after replay_throughput_bench)" --replay-once "$trace" hazards 16
          perf_report /dev/shm/clastrace_rep16.data pid ;;
    prof-cap) VK_ICD_FILENAMES=$icd VK_DRIVER_FILES=$icd VK_ADD_LAYER_PATH=$here/layer-after \
              VK_INSTANCE_LAYERS=VK_LAYER_CLASTRACE_capture CLASTRACE_STATS=1 CLASTRACE_OUTPUT=/dev/shm/c.clt \
              profile cap taskset -c 2-5 "$(bin after capture_frames_app)" frames 240 --clusters 256 ;;
    *) echo "device_run.sh: no part '$part'"; return 2 ;;
  esac
}

for part in "$@"; do
  log=$OUT/$part.txt
  echo "== $part $(date -u +%T) nproc $(nproc) $(lscpu | grep 'Model name' | tr -s ' ')" > "$log"
  run_part "$part" >> "$log" 2>&1
  echo "rc $? $(date -u +%T)" >> "$log"
done
