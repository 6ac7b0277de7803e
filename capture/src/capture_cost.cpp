// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/capture_cost.h"

#include <chrono>
#include <cstdio>
#include <ctime>

namespace clastrace::capture {
namespace {

struct AtomicTotal {
    std::atomic<uint64_t> count{0}, wall_ns{0}, cpu_ns{0};
};
std::array<AtomicTotal, size_t(CostPhase::kCount)> phases;
std::array<std::atomic<uint64_t>, size_t(CostThread::kCount)> threads{};
thread_local bool layerThread = false;
thread_local std::array<uint64_t, size_t(CostPhase::kCount)> thread_wall_ns{};

const char* const kPhaseNames[] = {
    "pause held (queue stalled)",
    "  reading inputs/outputs",
    "  engine (served build)",
    "  buffers copied into the engine's image",
    "    of which into fresh pages (none in the region pool)",
    "served records completed",
    "served regions made ready between pauses",
    "worker waiting for sink",
    "waiting for the sink past its memory bound",
    "app threads in sink",
    "  waiting for sink lock",
    "timestamp readback",
    "sink: emitting submissions",
    "  snapshots (merge, hash, store)",
    "periodic flush",
    "vkDestroyDevice flush",
    "host-write watch",
    "    driver BLAS builds (traceable)",
};
static_assert(sizeof kPhaseNames / sizeof kPhaseNames[0] == size_t(CostPhase::kCount));

const char* const kThreadNames[] = {"pause worker", "sink emitter", "trace compressor"};
static_assert(sizeof kThreadNames / sizeof kThreadNames[0] == size_t(CostThread::kCount));

}  // namespace

uint64_t thread_cpu_ns() {
    timespec t{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return uint64_t(t.tv_sec) * 1000000000ull + uint64_t(t.tv_nsec);
}

uint64_t wall_ns() {
    return uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(
                        std::chrono::steady_clock::now().time_since_epoch())
                        .count());
}

void add_cost(CostPhase phase, uint64_t wall, uint64_t cpu) {
    AtomicTotal& t = phases[size_t(phase)];
    t.count.fetch_add(1, std::memory_order_relaxed);
    t.wall_ns.fetch_add(wall, std::memory_order_relaxed);
    t.cpu_ns.fetch_add(cpu, std::memory_order_relaxed);
    thread_wall_ns[size_t(phase)] += wall;
}

uint64_t thread_cost_wall_ns(CostPhase phase) { return thread_wall_ns[size_t(phase)]; }

CostTotal cost_total(CostPhase phase) {
    const AtomicTotal& t = phases[size_t(phase)];
    return {t.count.load(), t.wall_ns.load(), t.cpu_ns.load()};
}

const char* cost_phase_name(CostPhase phase) { return kPhaseNames[size_t(phase)]; }

void add_thread_cpu(CostThread thread, uint64_t cpu) { threads[size_t(thread)].fetch_add(cpu); }
uint64_t thread_cpu_total(CostThread thread) { return threads[size_t(thread)].load(); }

void mark_layer_thread() { layerThread = true; }
bool on_layer_thread() { return layerThread; }

std::vector<std::string> cost_report(const std::vector<std::string>& extra) {
    std::vector<std::string> lines;
    char line[256];
    lines.push_back("stats: phase | count | wall ms | CPU ms");
    for (size_t i = 0; i < size_t(CostPhase::kCount); ++i) {
        const CostTotal t = cost_total(CostPhase(i));
        if (!t.count) continue;
        if (t.cpu_ns)
            std::snprintf(line, sizeof line, "stats: %s | %llu | %.3f | %.3f", kPhaseNames[i],
                          (unsigned long long)t.count, double(t.wall_ns) / 1e6,
                          double(t.cpu_ns) / 1e6);
        else
            std::snprintf(line, sizeof line, "stats: %s | %llu | %.3f | -", kPhaseNames[i],
                          (unsigned long long)t.count, double(t.wall_ns) / 1e6);
        lines.push_back(line);
    }
    for (size_t i = 0; i < size_t(CostThread::kCount); ++i) {
        const uint64_t cpu = thread_cpu_total(CostThread(i));
        if (!cpu) continue;
        std::snprintf(line, sizeof line, "stats: thread %s CPU ms: %.3f", kThreadNames[i],
                      double(cpu) / 1e6);
        lines.push_back(line);
    }
    for (const std::string& e : extra) lines.push_back("stats: " + e);
    return lines;
}

}  // namespace clastrace::capture
