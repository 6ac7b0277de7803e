// Background threads wait while a pause is handled, and no longer than their limit.
#include "clastrace/capture/foreground_gate.h"

#include <gtest/gtest.h>

#include <atomic>
#include <optional>
#include <thread>

using namespace clastrace::capture;

TEST(ForegroundGate, IdleGateDoesNotWait) {
  ForegroundGate gate;
  EXPECT_FALSE(gate.busy());
  gate.waitWhileBusy(std::chrono::hours(1));  // returns at once, or the test hangs
}

TEST(ForegroundGate, WaiterResumesWhenTheLastScopeEnds) {
  ForegroundGate gate;
  std::atomic<bool> resumed{false};
  std::optional<ForegroundGate::Scope> outer(std::in_place, gate);
  std::optional<ForegroundGate::Scope> inner(std::in_place, gate);  // two pauses at once
  std::thread background([&] {
    gate.waitWhileBusy(std::chrono::hours(1));
    resumed = true;
  });
  inner.reset();
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_FALSE(resumed.load()) << "resumed while a pause was still handled";
  EXPECT_TRUE(gate.busy());
  outer.reset();
  background.join();  // hangs (test timeout) if the last leave does not wake it
  EXPECT_TRUE(resumed.load());
  EXPECT_FALSE(gate.busy());
}

TEST(ForegroundGate, WaitIsBoundedByItsLimit) {
  ForegroundGate gate;
  ForegroundGate::Scope pause(gate);  // never ends during the test
  gate.waitWhileBusy(std::chrono::milliseconds(1));  // background work must not starve
  EXPECT_TRUE(gate.busy());
}
