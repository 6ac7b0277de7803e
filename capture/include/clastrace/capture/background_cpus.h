// SPDX-License-Identifier: Apache-2.0
// Where the capture's background threads run: the sink's (`clastrace-sink`) and the trace
// compressor's (`clastrace-zstd`). Both already yield to every normal thread (SCHED_IDLE), but
// on the application's own cores they still evict its caches and take the cores its engine
// threads wake on; measured on the H100 machine, moving them to other cores took 4-12 points off
// the capture's cost (docs/benchmarks.md, round 3).
//
// CLASTRACE_BACKGROUND_CPUS:
//   spare (default)  the online CPUs that the thread creating the capture may not run on (an
//                    application started under `taskset` or a narrowed affinity), leaving out
//                    those the kernel keeps apart (isolcpus, nohz_full: someone reserved them)
//                    and, unless only they are left, the SMT siblings of the application's
//                    CPUs (a sibling shares the core an engine thread runs on), when there are
//                    any; otherwise the application's own, as with `app`
//   app              inherited from the application: the old placement
//   a list, "6-7,12" those CPUs (0-based, as `taskset -c` takes them)
// The application's CPUs are those of the thread creating the first device (what `taskset`
// set), not the union of all its threads': drivers' own threads may widen theirs (Mesa's queues
// reset theirs to every CPU), which would leave nothing spare. A thread of the application
// pinned outside that set may meet the background threads on its CPU; they still yield to it.
// The pause worker and the served engine's threads stay with the application: they are on its
// path. Placement is best effort: a CPU the process's cpuset excludes is refused by the kernel,
// and the threads then keep the application's CPUs (the stats line says which they got).
#pragma once

#include <pthread.h>

#include <optional>
#include <string>
#include <vector>

namespace clastrace::capture {

struct BackgroundCpus {
    enum class Mode { kSpare, kApp, kList };
    Mode mode = Mode::kSpare;
    std::vector<unsigned> list;  // Mode::List: ascending, no repeats
};

// "0-3,8" -> {0,1,2,3,8}: comma-separated CPUs and inclusive ranges, each CPU below 4096.
std::optional<std::vector<unsigned>> parse_cpu_list(const std::string& text);
// The inverse, ranges folded: {0,1,2,3,8} -> "0-3,8"; "none" when empty.
std::string format_cpu_list(const std::vector<unsigned>& cpus);

// The CPUs the background threads should be given, from the machine's online CPUs, the
// calling (application) thread's allowed ones, the reserved ones and the allowed ones' SMT
// siblings; empty means: leave them where they were created.
std::vector<unsigned> background_cpus_for(const BackgroundCpus& setting,
                                          const std::vector<unsigned>& online,
                                          const std::vector<unsigned>& allowed,
                                          const std::vector<unsigned>& reserved = {},
                                          const std::vector<unsigned>& siblings = {});

std::vector<unsigned> online_cpus();    // /sys/devices/system/cpu/online; empty if unknown
std::vector<unsigned> reserved_cpus();  // /sys/devices/system/cpu/{isolated,nohz_full}
// The other hardware threads of the cores that `cpus` (ascending) are on, not in `cpus`
// (/sys/devices/system/cpu/cpuN/topology/thread_siblings_list); empty without SMT or if unknown.
std::vector<unsigned> smt_siblings(const std::vector<unsigned>& cpus);
// A thread's affinity; empty if unknown.
std::vector<unsigned> thread_cpus(pthread_t thread);
std::vector<unsigned> calling_thread_cpus();
// Restricts a thread to `cpus`. False (and the thread as it was) when the kernel refuses, e.g.
// none of them is in the process's cpuset. Placing a thread from its creator does not wait for
// it to run (a SCHED_IDLE thread may not run for a long time on a busy machine).
bool place_thread(pthread_t thread, const std::vector<unsigned>& cpus);
bool place_calling_thread(const std::vector<unsigned>& cpus);

}  // namespace clastrace::capture
