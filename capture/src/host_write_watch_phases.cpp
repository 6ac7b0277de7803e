// SPDX-License-Identifier: Apache-2.0
#include "host_write_watch_phases.h"

#include "clastrace/capture/capture_cost.h"

#include <cstdio>

namespace clastrace::capture {
namespace {

struct PhaseName {
    WatchCall call;
    const char* name;
};

const PhaseName kPhases[] = {
    {WatchCall::kSubmit, "submit: lock wait"},
    {WatchCall::kSubmit, "submit: earlier submissions looked at"},
    {WatchCall::kSubmit, "submit: pointer walks"},
    {WatchCall::kSubmit, "submit: ranges resolved"},
    {WatchCall::kSubmit, "submit: guard (probe, mprotect read-only)"},
    {WatchCall::kSubmit, "submit: hashed (ranges the guard cannot hold)"},
    {WatchCall::kSubmit, "submit: kept (oldest forgotten past the bound)"},
    {WatchCall::kPause, "pause: lock wait"},
    {WatchCall::kPause, "pause: compare with the submission"},
    {WatchCall::kWait, "wait: lock wait"},
    {WatchCall::kWait, "wait: look and compare"},
    {WatchCall::kWait, "wait: unwatch (mprotect writable)"},
};
static_assert(sizeof kPhases / sizeof kPhases[0] == size_t(WatchPhase::kCount));

double ms(uint64_t ns) { return double(ns) / 1e6; }

}  // namespace

std::vector<std::string> WatchPhaseTotals::lines(const PageGuard::Counts* guard) const {
    std::vector<std::string> out;
    char line[400];
    for (size_t i = 0; i < size_t(WatchPhase::kCount); ++i) {
        const uint64_t calls = calls_[size_t(kPhases[i].call)].load(std::memory_order_relaxed);
        if (!calls) continue;
        std::snprintf(line, sizeof line, "host-write watch phase: %s | %llu | %.3f",
                      kPhases[i].name, (unsigned long long)calls,
                      ms(ns_[i].load(std::memory_order_relaxed)));
        out.push_back(line);
    }
    std::snprintf(line, sizeof line,
                  "host-write watch ranges found by the submissions' walks: %llu",
                  (unsigned long long)ranges_found_.load(std::memory_order_relaxed));
    out.push_back(line);
    if (!guard) return out;
    auto per_call = [](uint64_t pages, uint64_t calls) {
        return calls ? double(pages) / double(calls) : 0.0;
    };
    std::snprintf(line, sizeof line,
                  "host-write watch mprotect: read-only %llu calls, %llu pages (%.1f a call), "
                  "%.3f ms (%.3f on CPU); writable %llu calls, %llu pages (%.1f a call), %.3f ms "
                  "(%.3f on CPU); before-images %llu pages, %.3f ms; faults after the waits %llu, "
                  "%.3f ms in the handler",
                  (unsigned long long)guard->protect_calls,
                  (unsigned long long)guard->protected_pages,
                  per_call(guard->protected_pages, guard->protect_calls), ms(guard->protect_ns),
                  ms(guard->protect_cpu_ns), (unsigned long long)guard->unprotect_calls,
                  (unsigned long long)guard->unprotected_pages,
                  per_call(guard->unprotected_pages, guard->unprotect_calls),
                  ms(guard->unprotect_ns), ms(guard->unprotect_cpu_ns),
                  (unsigned long long)guard->faults, ms(guard->before_image_ns),
                  (unsigned long long)guard->resting_faults, ms(guard->resting_fault_ns));
    out.push_back(line);
    return out;
}

WatchLaps::WatchLaps(WatchPhaseTotals& totals, WatchCall call) : totals_(totals), last_(wall_ns()) {
    totals_.add_call(call);
}

void WatchLaps::lap(WatchPhase phase) {
    const uint64_t now = wall_ns();
    totals_.add(phase, now - last_);
    last_ = now;
}

}  // namespace clastrace::capture
