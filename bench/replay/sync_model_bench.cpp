// SPDX-License-Identifier: Apache-2.0
// Throughput and memory of SyncModel (hazard checking) against a no-op consumer of the same
// pre-generated event stream. The real peer is replay without hazard checking; until
// replay exists, the no-op consumer bounds what feeding the events costs by itself.
//
// Usage: replay_sync_bench [max_accesses=1000000] [workload name prefix]
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

#include <sys/resource.h>
#include <time.h>

#include "clastrace/replay/sync_model.h"

using namespace clastrace::replay;

namespace {

constexpr StageMask kAsBuild = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
constexpr AccessMask kAsRead = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR;
constexpr AccessMask kAsWrite = VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;

struct Event {
    enum Kind : uint8_t { kAccess, kBarrier, kBegin, kEnd, kFenceWait } kind;
    CommandRef command;
    Access access;
    MemoryBarrier barrier;
    QueueId queue = 0;    // kBegin
    uint64_t wait = 0;    // kBegin: binary semaphore to wait on (0 = none)
    uint64_t signal = 0;  // kEnd: binary semaphore to signal (0 = none)
};

// Cluster builds the way an engine issues them each frame: upload the infos, barrier, build
// CLAS batches (infos, count, scratch, implicit data, addresses, sizes), barrier, build BLAS
// reading the CLAS, wait for the frame's fence. `live_frames` frames stay in flight.
std::vector<Event> clas_frames(std::size_t accesses, int batches_per_frame, int live_frames) {
    std::vector<Event> ev;
    std::mt19937_64 rng(1);
    std::size_t n = 0;
    uint32_t submission = 0;
    while (n < accesses) {
        const uint64_t base = (submission % uint32_t(live_frames)) * 0x10000000ull;
        ev.push_back({Event::kBegin, {}, {}, {}});
        uint32_t cmd = 0;
        auto access = [&](const char* name, uint64_t b, uint64_t e, StageMask st, AccessMask ac,
                          bool w, const char* f, bool same_command) {
            if (!same_command) ++cmd;
            ev.push_back(
                {Event::kAccess, {submission, 0, 1, cmd, name}, {{b, e}, st, ac, w, f}, {}});
            ++n;
        };
        auto barrier = [&](StageMask s, AccessMask sa, StageMask d, AccessMask da) {
            ev.push_back({Event::kBarrier,
                          {submission, 0, 1, ++cmd, "vkCmdPipelineBarrier2"},
                          {},
                          {s, sa, d, da}});
        };
        for (int batch = 0; batch < batches_per_frame; ++batch) {
            const uint64_t infos = base + 0x100000 + uint64_t(batch) * 0x10000;
            access("vkCmdCopyBuffer", infos, infos + 0x8000, VK_PIPELINE_STAGE_2_COPY_BIT,
                   VK_ACCESS_2_TRANSFER_WRITE_BIT, true, "dstBuffer", false);
        }
        barrier(VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, kAsBuild,
                VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
        for (int batch = 0; batch < batches_per_frame; ++batch) {
            const uint64_t infos = base + 0x100000 + uint64_t(batch) * 0x10000;
            const uint64_t clas = base + 0x1000000 + uint64_t(batch) * 0x100000;
            const char* build = "vkCmdBuildClusterAccelerationStructureIndirectNV";
            access(build, infos, infos + 0x8000, kAsBuild, VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT,
                   false, "srcInfosArray", false);
            access(build, infos + 0x8000, infos + 0x8004, kAsBuild,
                   VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT, false, "srcInfosCount", true);
            // Vertex and index data per cluster: 32 reads of scattered buffers.
            for (int c = 0; c < 32; ++c) {
                const uint64_t v = base + 0x8000000 + (rng() % 4096) * 0x400;
                access(build, v, v + 0x300, kAsBuild, kAsRead, false,
                       "srcInfosArray[i].vertexBuffer", true);
            }
            access(build, base + 0x50000, base + 0x60000, kAsBuild, kAsRead | kAsWrite, true,
                   "scratchData", true);
            access(build, clas, clas + 0x80000, kAsBuild, kAsWrite, true, "dstImplicitData", true);
            access(build, clas + 0x80000, clas + 0x80400, kAsBuild, kAsWrite, true,
                   "dstAddressesArray", true);
            access(build, clas + 0x80400, clas + 0x80800, kAsBuild, kAsWrite, true, "dstSizesArray",
                   true);
            barrier(kAsBuild, kAsWrite, kAsBuild, kAsRead | kAsWrite);
        }
        for (int batch = 0; batch < batches_per_frame; ++batch) {
            const uint64_t clas = base + 0x1000000 + uint64_t(batch) * 0x100000;
            const char* build = "vkCmdBuildClusterAccelerationStructureIndirectNV";
            access(build, clas, clas + 0x80000, kAsBuild, kAsRead, false, "clusterReferences",
                   false);
            access(build, base + 0x50000, base + 0x60000, kAsBuild, kAsRead | kAsWrite, true,
                   "scratchData", true);
            access(build, base + 0x4000000 + uint64_t(batch) * 0x10000,
                   base + 0x4000000 + uint64_t(batch) * 0x10000 + 0x8000, kAsBuild, kAsWrite, true,
                   "dstImplicitData", true);
            barrier(kAsBuild, kAsWrite, kAsBuild, kAsRead | kAsWrite);
        }
        barrier(kAsBuild, kAsWrite, VK_PIPELINE_STAGE_2_HOST_BIT, VK_ACCESS_2_HOST_READ_BIT);
        ev.push_back({Event::kEnd, {}, {}, {}});
        ++submission;
        if (submission >= uint32_t(live_frames)) ev.push_back({Event::kFenceWait, {}, {}, {}});
    }
    return ev;
}

// A transfer queue uploads each frame's infos and vertex data, the compute queue waits on a
// semaphore and builds; the compute queue signals back before the next upload (the WAR).
std::vector<Event> two_queue_frames(std::size_t accesses, int batches_per_frame) {
    std::vector<Event> ev;
    std::size_t n = 0;
    uint32_t submission = 0;
    uint64_t frame = 0;
    while (n < accesses) {
        uint32_t cmd = 0;
        auto access = [&](const char* name, uint64_t b, uint64_t e, StageMask st, AccessMask ac,
                          bool w, const char* f, bool same) {
            if (!same) ++cmd;
            ev.push_back(
                {Event::kAccess, {submission, 0, 1, cmd, name}, {{b, e}, st, ac, w, f}, {}});
            ++n;
        };
        Event begin{Event::kBegin, {}, {}, {}};
        begin.queue = 1;
        begin.wait = frame ? 2 : 0;
        ev.push_back(begin);
        for (int batch = 0; batch < batches_per_frame; ++batch) {
            const uint64_t infos = 0x100000 + uint64_t(batch) * 0x10000;
            access("vkCmdCopyBuffer", infos, infos + 0x8000, VK_PIPELINE_STAGE_2_COPY_BIT,
                   VK_ACCESS_2_TRANSFER_WRITE_BIT, true, "dstBuffer", false);
        }
        Event end{Event::kEnd, {}, {}, {}};
        end.signal = 1;
        ev.push_back(end);
        ++submission;
        cmd = 0;
        begin.queue = 0;
        begin.wait = 1;
        ev.push_back(begin);
        for (int batch = 0; batch < batches_per_frame; ++batch) {
            const uint64_t infos = 0x100000 + uint64_t(batch) * 0x10000;
            const uint64_t clas = 0x1000000 + uint64_t(batch) * 0x100000;
            const char* build = "vkCmdBuildClusterAccelerationStructureIndirectNV";
            access(build, infos, infos + 0x8000, kAsBuild, VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT,
                   false, "srcInfosArray", false);
            access(build, 0x50000, 0x60000, kAsBuild, kAsRead | kAsWrite, true, "scratchData",
                   true);
            access(build, clas, clas + 0x80000, kAsBuild, kAsWrite, true, "dstImplicitData", true);
            ev.push_back({Event::kBarrier,
                          {submission, 0, 1, ++cmd, "vkCmdPipelineBarrier2"},
                          {},
                          {kAsBuild, kAsWrite, kAsBuild, kAsRead | kAsWrite}});
        }
        end.signal = 2;
        ev.push_back(end);
        ++submission;
        ++frame;
    }
    return ev;
}

// One barrier before every access, over `ranges` live buffers, no host waits: the lazy log's
// worst case when `full` is false (each touch replays every barrier since the last one).
std::vector<Event> barrier_per_access(std::size_t accesses, std::size_t ranges, bool full) {
    std::vector<Event> ev;
    std::mt19937_64 rng(2);
    ev.push_back({Event::kBegin, {}, {}, {}});
    for (std::size_t i = 0; i < accesses; ++i) {
        const MemoryBarrier b =
            full ? MemoryBarrier{VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT, VK_ACCESS_2_MEMORY_WRITE_BIT,
                                 VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT,
                                 VK_ACCESS_2_MEMORY_READ_BIT | VK_ACCESS_2_MEMORY_WRITE_BIT}
                 : MemoryBarrier{kAsBuild, kAsWrite, kAsBuild, kAsRead | kAsWrite};
        ev.push_back({Event::kBarrier, {0, 0, 1, uint32_t(2 * i), "vkCmdPipelineBarrier2"}, {}, b});
        const uint64_t r = rng() % ranges;
        const bool write = rng() % 3 == 0;
        ev.push_back({Event::kAccess,
                      {0, 0, 1, uint32_t(2 * i + 1), "build"},
                      {{r * 0x1000, r * 0x1000 + 0x800},
                       kAsBuild,
                       write ? kAsRead | kAsWrite : kAsRead,
                       write,
                       "f"},
                      {}});
    }
    ev.push_back({Event::kEnd, {}, {}, {}});
    return ev;
}

std::size_t count_accesses(const std::vector<Event>& ev) {
    std::size_t n = 0;
    for (const Event& e : ev) n += e.kind == Event::kAccess;
    return n;
}

// Thread CPU time: the build machine is shared, and wall time there measures the neighbours.
double cpu_seconds() {
    timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return double(ts.tv_sec) + double(ts.tv_nsec) * 1e-9;
}

struct Result {
    double seconds;
    std::size_t peak_bytes;
    std::size_t hazards;
    uint64_t applied;
};

Result run_model(const std::vector<Event>& ev) {
    SyncModel model;
    std::size_t peak = 0;
    uint32_t submission = 0;
    const double t0 = cpu_seconds();
    for (const Event& e : ev) {
        switch (e.kind) {
        case Event::kAccess: model.record_access(e.command, e.access); break;
        case Event::kBarrier:
            model.pipeline_barrier(e.command, DependencyInfo{std::span(&e.barrier, 1), {}, 0});
            break;
        case Event::kBegin: {
            const SemaphoreWait w{e.wait, 0, kAsBuild | VK_PIPELINE_STAGE_2_COPY_BIT};
            model.begin_submission(e.queue, submission,
                                   e.wait ? std::span(&w, 1) : std::span<const SemaphoreWait>());
            break;
        }
        case Event::kEnd: {
            const SemaphoreSignal sig{e.signal, 0};
            model.end_submission(e.signal ? std::span(&sig, 1) : std::span<const SemaphoreSignal>(),
                                 100 + submission++);
            peak = std::max(peak, model.memory_bytes());
            break;
        }
        case Event::kFenceWait: model.wait_for_fence(100 + submission - 3); break;
        }
    }
    const double t1 = cpu_seconds();
    peak = std::max(peak, model.memory_bytes());
    return {t1 - t0, peak, model.hazards().size(), model.stats().log_entries_applied};
}

// Touches every field a consumer would read, so the compiler cannot drop the loop.
double run_noop(const std::vector<Event>& ev) {
    uint64_t sum = 0;
    const double t0 = cpu_seconds();
    for (const Event& e : ev) {
        sum += e.access.range.begin ^ e.access.range.end ^ e.access.stage ^ e.barrier.src_stages ^
               e.command.command;
        asm volatile("" : "+r"(sum));
    }
    const double t1 = cpu_seconds();
    if (sum == 42) std::puts("");
    return t1 - t0;
}

const char* g_filter = "";

template <class MakeStream>
void row(const std::string& name, MakeStream make) {
    if (!name.starts_with(g_filter)) return;
    const std::vector<Event> ev = make();
    const std::size_t n = count_accesses(ev);
    const Result r = run_model(ev);
    const double noop = run_noop(ev);
    std::printf("| %-44s | %9zu | %12.3g | %8.1f | %10.1f | %9.1f | %7zu | %9.2f |\n", name.c_str(),
                n, double(n) / r.seconds, r.seconds * 1e9 / double(n), r.seconds / noop,
                double(r.peak_bytes) / 1024.0, r.hazards, double(r.applied) / double(n));
    std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
    const std::size_t max_accesses = argc > 1 ? std::strtoull(argv[1], nullptr, 10) : 1000000;
    if (argc > 2) g_filter = argv[2];  // only workloads whose name starts with this
    std::printf(
        "SyncModel hazard checking vs a no-op consumer of the same events (thread CPU time, 1 "
        "thread)\n\n");
    std::printf("| %-44s | %9s | %12s | %8s | %10s | %9s | %7s | %9s |\n", "workload", "accesses",
                "accesses/s", "ns/acc", "x no-op", "peak KiB", "hazards", "log/acc");
    std::printf("|%s|%s|%s|%s|%s|%s|%s|%s|\n", std::string(46, '-').c_str(),
                std::string(11, '-').c_str(), std::string(14, '-').c_str(),
                std::string(10, '-').c_str(), std::string(12, '-').c_str(),
                std::string(11, '-').c_str(), std::string(9, '-').c_str(),
                std::string(11, '-').c_str());
    for (std::size_t n = 1000; n <= max_accesses; n *= 10) {
        row("CLAS frames, 16 batches, " + std::to_string(n), [&] { return clas_frames(n, 16, 3); });
    }
    for (std::size_t n = 1000; n <= max_accesses; n *= 10)
        row("2 queues + semaphores, no host wait, " + std::to_string(n),
            [&] { return two_queue_frames(n, 16); });
    for (std::size_t n = 1000; n <= max_accesses; n *= 10)
        row("no barriers at all (all hazards), " + std::to_string(n), [&] {
            auto ev = barrier_per_access(n, 4096, false);
            std::erase_if(ev, [](const Event& e) { return e.kind == Event::kBarrier; });
            return ev;
        });
    for (std::size_t n = 1000; n <= max_accesses; n *= 10)
        row("full barrier per access, " + std::to_string(n),
            [&] { return barrier_per_access(n, 4096, true); });
    for (std::size_t n = 1000; n <= max_accesses; n *= 10)
        row("AS barrier per access, 64 bufs, " + std::to_string(n),
            [&] { return barrier_per_access(n, 64, false); });
    for (std::size_t n = 1000; n <= max_accesses; n *= 10)
        row("AS barrier per access, 4096 bufs, " + std::to_string(n),
            [&] { return barrier_per_access(n, 4096, false); });
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    std::printf("\nmax RSS of the whole run (streams included): %ld MiB\n", ru.ru_maxrss / 1024);
    return 0;
}
