// SPDX-License-Identifier: Apache-2.0
#include "idle_priority.h"

#include <sched.h>
#include <sys/resource.h>
#include <unistd.h>

#include <fstream>
#include <string>

namespace clastrace::capture {
namespace {

bool set_policy(pthread_t thread, int policy) {
    sched_param param{};
    return pthread_setschedparam(thread, policy, &param) == 0;
}

// CAP_SYS_NICE (bit 23) in the effective set, from /proc/self/status.
bool has_sys_nice_capability() {
    std::ifstream status("/proc/self/status");
    for (std::string line; std::getline(status, line);)
        if (line.rfind("CapEff:", 0) == 0) {
            const unsigned long long caps = std::stoull(line.substr(7), nullptr, 16);
            return (caps >> 23) & 1;
        }
    return false;
}

// Whether a thread put in SCHED_IDLE may be put back in SCHED_OTHER at nice 0.
bool may_leave_idle_class() {
    rlimit limit{};
    if (getrlimit(RLIMIT_NICE, &limit) == 0 && limit.rlim_cur >= 20) return true;
    return has_sys_nice_capability();
}

}  // namespace

IdlePriority::IdlePriority() : idle_class_(may_leave_idle_class()) {}

void IdlePriority::enter_on_calling_thread() {
    if (!idle_class_ || !set_policy(pthread_self(), SCHED_IDLE)) {
        (void)setpriority(PRIO_PROCESS, id_t(gettid()), kFallbackNice);
        return;
    }
    if (raises_.load(std::memory_order_acquire) != settled_)
        (void)set_policy(pthread_self(), SCHED_OTHER);
}

void IdlePriority::raise() {
    if (!idle_class_) return;
    raises_.fetch_add(1, std::memory_order_acq_rel);
    (void)set_policy(thread_, SCHED_OTHER);
}

void IdlePriority::settle() {
    if (!idle_class_) return;
    const uint64_t seen = raises_.load(std::memory_order_acquire);
    if (seen == settled_) return;  // not raised since it last settled: in SCHED_IDLE already
    settled_ = seen;
    (void)set_policy(thread_, SCHED_IDLE);
    // A raise between the load and the call above may have been undone by it: restore it.
    if (raises_.load(std::memory_order_acquire) != seen) (void)set_policy(thread_, SCHED_OTHER);
}

}  // namespace clastrace::capture
