// SPDX-License-Identifier: Apache-2.0
// A background thread that runs in Linux's SCHED_IDLE class, so that every normal thread (the
// application's, the served engine's, a driver's queue thread spinning on an event) comes first,
// and that another thread can lift into the normal class while it needs the background thread
// to make progress: a lock the background thread holds, memory only it frees. A SCHED_IDLE
// thread on a busy machine may get no CPU for seconds; whoever waits for it would wait as long
// (the pause worker waiting for the sink's lock stalled the queue past a 60 s fence timeout on
// a loaded 2-core machine). Raising by hand is the priority inheritance a plain mutex lacks.
//
// Leaving SCHED_IDLE again needs CAP_SYS_NICE or an RLIMIT_NICE that allows nice 0; where the
// process has neither the thread takes nice 10 instead, which no normal thread starves, and is
// never raised.
#pragma once

#include <pthread.h>

#include <atomic>
#include <cstdint>

namespace clastrace::capture {

class IdlePriority {
public:
    static constexpr int kFallbackNice = 10;

    IdlePriority();
    // From the thread's creator, before anyone may raise it: which thread raise() lifts.
    void attach(pthread_t thread) { thread_ = thread; }
    // On the background thread, first thing: SCHED_IDLE (raised at once if a raise came
    // before), or nice 10 where the class could not be left again.
    void enter_on_calling_thread();
    // From any thread: the background thread runs in the normal class until it settles.
    void raise();
    // On the background thread when it has nothing left that others wait for: back to SCHED_IDLE,
    // unless raised again in the meantime.
    void settle();
    uint64_t raises() const { return raises_.load(std::memory_order_relaxed); }
    bool idle_class() const { return idle_class_; }

private:
    pthread_t thread_{};
    const bool idle_class_;  // SCHED_IDLE (or raised out of it), not nice 10
    std::atomic<uint64_t> raises_{0};
    uint64_t settled_ = 0;  // raises_ when the thread last settled (its own thread only)
};

}  // namespace clastrace::capture
