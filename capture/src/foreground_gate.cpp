#include "clastrace/capture/foreground_gate.h"

namespace clastrace::capture {

void ForegroundGate::leave() {
  if (busy_.fetch_sub(1, std::memory_order_acq_rel) != 1) return;
  std::lock_guard lock(mutex_);  // a waiter between its check and its wait still sees the notify
  idle_.notify_all();
}

void ForegroundGate::waitWhileBusy(std::chrono::microseconds limit) {
  if (!busy()) return;
  std::unique_lock lock(mutex_);
  idle_.wait_for(lock, limit, [this] { return !busy(); });
}

ForegroundGate& foregroundGate() {
  static ForegroundGate gate;
  return gate;
}

}  // namespace clastrace::capture
