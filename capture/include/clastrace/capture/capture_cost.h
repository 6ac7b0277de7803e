// SPDX-License-Identifier: Apache-2.0
// Where capture's time goes (CLASTRACE_STATS=1): process-wide totals of wall and CPU time per
// phase of the capture path, kept always (a few clock reads per pause and per submission) and
// printed as one block at vkDestroyDevice. A user who finds capture slow learns which knob or
// which part of the application's pattern is to blame; the overhead bench prints it as a table.
#pragma once

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

namespace clastrace::capture {

enum class CostPhase : uint8_t {
    kPauseHeld,    // pause worker: the queue is stalled (event seen -> release)
    kPauseRead,    //   of which: the capture reading the command's inputs (and outputs)
    kPauseEngine,  //   of which: the served build's engine run
    // of which: served buffers copied into the engine's image, once per pause whoever reads them
    // first (the capture's walk, or the engine's run): left out of the two lines above, so that
    // they compare between capture + serving and serving only.
    kPauseCopyIn,
    kPauseCopyInFresh,        //   of which: into fresh region bytes, the region pool having none
    kServedRecordCompletion,  // a served record completed where it is written: output walk, buffer naming
    kRegionsMadeReady,        // pause worker between pauses: served region pool regions faulted in
    kWorkerSinkWait,          // pause worker waiting for the sink's lock
    kSinkBoundWait,  // a deliverer waiting for the sink to write, past its memory bound (1 GiB)
    kAppSinkCall,    // application threads inside the sink (records, submissions, timestamps)
    kAppSinkWait,    //   of which: waiting for the sink's lock
    kTimestampRead,  // application threads reading the layer's GPU timestamps
    kEmit,           // sink thread: turning finished submissions into records and snapshots
    kSnapshot,       //   of which: merging ranges, hashing and storing contents
    kPeriodicFlush,  // sink thread: CLASTRACE_FLUSH_MS chunk ends (waits for the compressor)
    kDeviceFlush,    // vkDestroyDevice: writing out everything captured (the application waits)
    kHostWrites,     // host-write watch: hashing mapped inputs at submit, pauses and waits
    kDriverBlas,     // inside kPauseEngine: device B building a command's traceable BLASes
    kCount
};

struct CostTotal {
    uint64_t count = 0;
    uint64_t wall_ns = 0;
    uint64_t cpu_ns = 0;  // 0 where the phase is timed by wall clock only
};

// The calling thread's CPU time (CLOCK_THREAD_CPUTIME_ID), nanoseconds.
uint64_t thread_cpu_ns();
uint64_t wall_ns();  // steady clock

void add_cost(CostPhase phase, uint64_t wall_ns, uint64_t cpu_ns = 0);
// The wall time the calling thread has added to `phase` so far (to leave nested phases out).
uint64_t thread_cost_wall_ns(CostPhase phase);
CostTotal cost_total(CostPhase phase);
const char* cost_phase_name(CostPhase phase);

// CPU time of the layer's own threads, added when each ends (pause worker) or reported by
// their owner (sink, trace writer) at report time.
enum class CostThread : uint8_t { kPauseWorker, kSinkEmitter, kTraceCompressor, kCount };
void add_thread_cpu(CostThread thread, uint64_t cpu_ns);
uint64_t thread_cpu_total(CostThread thread);

// Times a scope into a phase; with `cpu` the thread's CPU time too (a system call each end).
class CostScope {
public:
    // `without`: a phase that may run inside this one and is left out of it (its own line has it).
    explicit CostScope(CostPhase phase, bool cpu = false, CostPhase without = CostPhase::kCount)
        : phase_(phase),
          cpu_(cpu),
          without_(without),
          wall_(wall_ns()),
          cpu_start_(cpu ? thread_cpu_ns() : 0),
          without_start_(nested_wall()) {}
    ~CostScope() {
        const uint64_t nested = nested_wall() - without_start_;
        const uint64_t wall = wall_ns() - wall_;
        add_cost(phase_, wall - std::min(wall, nested), cpu_ ? thread_cpu_ns() - cpu_start_ : 0);
    }
    CostScope(const CostScope&) = delete;
    CostScope& operator=(const CostScope&) = delete;

private:
    uint64_t nested_wall() const {
        return without_ == CostPhase::kCount ? 0 : thread_cost_wall_ns(without_);
    }
    CostPhase phase_;
    bool cpu_;
    CostPhase without_;
    uint64_t wall_, cpu_start_, without_start_;
};

// Marks the calling thread as one of the layer's (sink waits are then counted as the worker's,
// not the application's).
void mark_layer_thread();
bool on_layer_thread();

// The report: one line per phase that ran, then `extra` lines (the sink's trace numbers).
std::vector<std::string> cost_report(const std::vector<std::string>& extra);

}  // namespace clastrace::capture
