// Background threads step aside while the application's queue waits on the layer.
//
// A pause stalls the application's queue, and a served build then runs in the engine on every
// core the application may use. The layer's background threads (the sink's emitter, the trace
// compressor) run in SCHED_IDLE, yet still take a core whenever a busy thread yields it (a TBB
// worker looking for work, a driver thread spinning on a fence) and keep it until the next
// scheduler tick: on the H100, capture cost 13 points more of the application's time with those
// threads on the application's cores than on others. So they wait at their next safe point (no
// lock held) while a pause is handled, for a bounded time: background work must not starve.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <mutex>

namespace clastrace::capture {

class ForegroundGate {
 public:
  void enter() { busy_.fetch_add(1, std::memory_order_acq_rel); }
  void leave();
  // Returns at once when no foreground work runs, else when it ends or `limit` passed.
  void waitWhileBusy(std::chrono::microseconds limit = std::chrono::milliseconds(20));
  bool busy() const { return busy_.load(std::memory_order_acquire) != 0; }

  class Scope {
   public:
    explicit Scope(ForegroundGate& gate) : gate_(gate) { gate_.enter(); }
    ~Scope() { gate_.leave(); }
    Scope(const Scope&) = delete;
    Scope& operator=(const Scope&) = delete;

   private:
    ForegroundGate& gate_;
  };

 private:
  std::atomic<int> busy_{0};
  std::mutex mutex_;
  std::condition_variable idle_;
};

// One per process: every device's pauses share the cores.
ForegroundGate& foregroundGate();

}  // namespace clastrace::capture
