// Where capture's time goes (CLASTRACE_STATS=1): process-wide totals of wall and CPU time per
// phase of the capture path, kept always (a few clock reads per pause and per submission) and
// printed as one block at vkDestroyDevice. A user who finds capture slow learns which knob or
// which part of the application's pattern is to blame; the overhead bench prints it as a table.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

namespace clastrace::capture {

enum class CostPhase : uint8_t {
  PauseHeld,      // pause worker: the queue is stalled (event seen -> release)
  PauseRead,      //   of which: the capture reading the command's inputs (and outputs)
  PauseEngine,    //   of which: the served build's engine run
  ServedRecordCompletion,  // a served record completed where it is written: output walk, buffer naming
  WorkerSinkWait, // pause worker waiting for the sink's lock
  AppSinkCall,    // application threads inside the sink (records, submissions, timestamps)
  AppSinkWait,    //   of which: waiting for the sink's lock
  TimestampRead,  // application threads reading the layer's GPU timestamps
  Emit,           // sink thread: turning finished submissions into records and snapshots
  Snapshot,       //   of which: merging ranges, hashing and storing contents
  PeriodicFlush,  // sink thread: CLASTRACE_FLUSH_MS chunk ends (waits for the compressor)
  DeviceFlush,    // vkDestroyDevice: writing out everything captured (the application waits)
  kCount
};

struct CostTotal {
  uint64_t count = 0;
  uint64_t wallNs = 0;
  uint64_t cpuNs = 0;  // 0 where the phase is timed by wall clock only
};

// The calling thread's CPU time (CLOCK_THREAD_CPUTIME_ID), nanoseconds.
uint64_t threadCpuNs();
uint64_t wallNs();  // steady clock

void addCost(CostPhase phase, uint64_t wallNs, uint64_t cpuNs = 0);
CostTotal costTotal(CostPhase phase);
const char* costPhaseName(CostPhase phase);

// CPU time of the layer's own threads, added when each ends (pause worker) or reported by
// their owner (sink, trace writer) at report time.
enum class CostThread : uint8_t { PauseWorker, SinkEmitter, TraceCompressor, kCount };
void addThreadCpu(CostThread thread, uint64_t cpuNs);
uint64_t threadCpuTotal(CostThread thread);

// Times a scope into a phase; with `cpu` the thread's CPU time too (a system call each end).
class CostScope {
 public:
  explicit CostScope(CostPhase phase, bool cpu = false)
      : phase_(phase), cpu_(cpu), wall_(wallNs()), cpuStart_(cpu ? threadCpuNs() : 0) {}
  ~CostScope() { addCost(phase_, wallNs() - wall_, cpu_ ? threadCpuNs() - cpuStart_ : 0); }
  CostScope(const CostScope&) = delete;
  CostScope& operator=(const CostScope&) = delete;

 private:
  CostPhase phase_;
  bool cpu_;
  uint64_t wall_, cpuStart_;
};

// Marks the calling thread as one of the layer's (sink waits are then counted as the worker's,
// not the application's).
void markLayerThread();
bool onLayerThread();

// The report: one line per phase that ran, then `extra` lines (the sink's trace numbers).
std::vector<std::string> costReport(const std::vector<std::string>& extra);

}  // namespace clastrace::capture
