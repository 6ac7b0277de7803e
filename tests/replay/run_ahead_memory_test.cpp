// SPDX-License-Identifier: Apache-2.0
// What a run ahead leaves behind (issue 23): glibc gives each worker thread a heap arena of its
// own, and a run's state that a worker allocated and the replay thread freed at the command's
// turn left every arena holding a window's worth of runs, so peak memory grew with the trace.
// This binary counts, through its own operator new and delete, the bytes the replay thread
// frees that another thread allocated: with runs ahead they must not grow with the trace's
// length (replay/src/cluster_speculation.h, RunBuffers).
#include "replay_bench_trace.h"

#include <clastrace/replay/replay_observer.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/testsupport/temp_trace_path.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <atomic>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <new>
#include <string>

namespace {

// Each block starts with its size and the thread that made it; kHeader keeps the rest aligned.
constexpr size_t kHeader = 16;
struct BlockHeader {
    uint64_t size;
    uint32_t thread;
};

std::atomic<uint32_t> next_thread{1};
thread_local uint32_t this_thread = 0;
uint32_t thread_tag() {
    if (this_thread == 0) this_thread = next_thread.fetch_add(1);
    return this_thread;
}

std::atomic<uint32_t> counted_thread{0};  // the replay thread while counting; 0: not counting
std::atomic<uint64_t> freed_elsewhere{0};

void* allocate(size_t size, size_t align) {
    const size_t front = align > kHeader ? align : kHeader;
    void* base = align > kHeader
                     ? std::aligned_alloc(align, (front + size + align - 1) / align * align)
                     : std::malloc(front + size);
    if (!base) throw std::bad_alloc();
    auto* block = static_cast<unsigned char*>(base) + front;
    auto* header = reinterpret_cast<BlockHeader*>(block - kHeader);
    header->size = size;
    header->thread = thread_tag();
    return block;
}

void release(void* p, size_t align) {
    if (!p) return;
    const size_t front = align > kHeader ? align : kHeader;
    auto* block = static_cast<unsigned char*>(p);
    const auto* header = reinterpret_cast<const BlockHeader*>(block - kHeader);
    const uint32_t counted = counted_thread.load(std::memory_order_relaxed);
    if (counted != 0 && thread_tag() == counted && header->thread != counted)
        freed_elsewhere.fetch_add(header->size, std::memory_order_relaxed);
    std::free(block - front);
}

}  // namespace

void* operator new(size_t size) { return allocate(size, 0); }
void* operator new[](size_t size) { return allocate(size, 0); }
void* operator new(size_t size, std::align_val_t align) { return allocate(size, size_t(align)); }
void* operator new[](size_t size, std::align_val_t align) { return allocate(size, size_t(align)); }
void* operator new(size_t size, const std::nothrow_t&) noexcept {
    try {
        return allocate(size, 0);
    } catch (...) {
        return nullptr;
    }
}
void* operator new[](size_t size, const std::nothrow_t&) noexcept {
    try {
        return allocate(size, 0);
    } catch (...) {
        return nullptr;
    }
}
void operator delete(void* p) noexcept { release(p, 0); }
void operator delete[](void* p) noexcept { release(p, 0); }
void operator delete(void* p, size_t) noexcept { release(p, 0); }
void operator delete[](void* p, size_t) noexcept { release(p, 0); }
void operator delete(void* p, std::align_val_t align) noexcept { release(p, size_t(align)); }
void operator delete[](void* p, std::align_val_t align) noexcept { release(p, size_t(align)); }
void operator delete(void* p, size_t, std::align_val_t align) noexcept {
    release(p, size_t(align));
}
void operator delete[](void* p, size_t, std::align_val_t align) noexcept {
    release(p, size_t(align));
}
void operator delete(void* p, const std::nothrow_t&) noexcept { release(p, 0); }
void operator delete[](void* p, const std::nothrow_t&) noexcept { release(p, 0); }

namespace {

using namespace clastrace;

// What the replay thread had freed when it finished each submission: the count without the
// teardown of the replay's pools at its end (bounded by the runs alive at once, not counted).
struct SubmissionEnds : replay::ReplayObserver {
    uint64_t freed = 0;
    void on_submission_end(uint32_t) override { freed = freed_elsewhere; }
};

struct Counted {
    uint64_t freed_elsewhere = 0;
    replay::ReplayOptions::RunAheadCounts counts;
};

// The replay bench's cluster frames of about `ops` ops, replayed on `threads` threads with runs
// ahead as asked, counting what the replay thread frees of other threads' blocks.
Counted replay_frames(uint64_t ops, uint32_t threads, bool run_ahead) {
    const std::string path =
        test::temp_trace_path("run_ahead_memory", "frames_" + std::to_string(ops) + ".clt");
    bench::BenchTraceShape shape;
    shape.target_ops = ops;
    bench::write_bench_trace(path, shape);
    traces::TraceError error;
    auto reader = traces::TraceReader::open(path, &error);
    EXPECT_TRUE(reader) << error.message;
    Counted c;
    if (!reader) return c;
    replay::ReplayOptions options;
    options.threads = threads;
    options.run_ahead = run_ahead;
    options.run_ahead_counts = &c.counts;
    SubmissionEnds ends;
    options.observer = &ends;
    freed_elsewhere = 0;
    counted_thread = thread_tag();  // replay_trace runs the replay on the calling thread
    const replay::ReplayReport report = replay::replay_trace(*reader, path, options);
    counted_thread = 0;
    c.freed_elsewhere = ends.freed;
    EXPECT_TRUE(report.clean());
    std::remove(path.c_str());
    return c;
}

// 125 and 500 frames of two CLAS builds and a BLAS, on 8 threads. Before session 12 the replay
// thread freed every run's engine record and written bytes: about 12 KB a run counted up to the
// last submission's end (7.3 MB for 600 runs on a loaded 2-core container). Now a run's buffers
// go back to the replay's pool and are emptied on the side that filled them. What is left is
// not zero: the engine's parallel loops of the commands in their turn (moves) and of runs the
// replay thread runs itself (no worker took them up by their turn) allocate on workers too;
// with every build in its turn that alone is 0.7 to 30 MB here, as busy as the workers are.
TEST(ReplayRunAheadMemory, ReplayThreadFreesLittleRunStateWhateverTheTraceLength) {
    for (uint64_t ops : {4000u, 16000u}) {
        const Counted ahead = replay_frames(ops, 8, true);
        EXPECT_GE(ahead.counts.started, ops / 32);
        EXPECT_GE(ahead.counts.stood, ahead.counts.started - 3);
        std::printf(
            "%llu ops: the replay thread freed %llu bytes of other threads' blocks with "
            "%llu runs ahead\n",
            (unsigned long long)ops, (unsigned long long)ahead.freed_elsewhere,
            (unsigned long long)ahead.counts.started);
        EXPECT_LT(ahead.freed_elsewhere, ahead.counts.started * 8192) << ops << " ops";
    }
}

}  // namespace
