// SPDX-License-Identifier: Apache-2.0
// The trace sink never makes the pause worker (or a host call holding the host-write watch's
// lock, which a pause takes) wait for its writer. The output is a FIFO that nobody reads until
// the test says so: a writer blocked for as long as the test likes, through the output rule's
// own FIFO support (traces/output_file.h). While a flush is stuck on it, holding the writer's
// lock, a build delivered past the sink's memory bound and an observed host write both return
// before anything reads the pipe: they did not wait for the writer. (Before, both took the
// writer's lock: the build to write the outbox itself past 256 MiB, the host write to store its
// bytes; on a loaded machine the queue stalled behind a writer in SCHED_IDLE for minutes.)
#include "clastrace/capture/capture_cost.h"
#include "clastrace/capture/capture_sink.h"

#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <fcntl.h>
#include <filesystem>
#include <fstream>
#include <future>
#include <random>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <thread>
#include <unistd.h>
#include <vector>

namespace clastrace::capture {
namespace {

namespace fs = std::filesystem;

constexpr uint64_t kBuffer = 0x55, kMemory = 0x66, kBufferAddress = 0x100000;
constexpr uint64_t kRangeBytes = 1u << 20, kRanges = 8;

// Submission `index` of command buffer `cb`, holding one KHR build (pause `pause`).
void submit_build(CaptureSink& sink, uint64_t index, uint64_t cb, uint64_t pause) {
    RecordedCommandBuffer recorded;
    recorded.command_buffer = cb;
    BuildAccelerationStructuresKHRCommand build;
    build.pause_id = pause;
    KhrBuildInfo info;
    info.info.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    build.infos.push_back(info);
    recorded.commands.push_back(build);
    sink.command_buffer_recorded(recorded);
    SubmissionRecord s;
    s.index = index;
    s.batches.push_back({{}, {cb}, {}});
    sink.queue_submitted(s);
}

ClusterBuildCapture captured_build(uint64_t index, uint64_t cb, uint64_t pause) {
    ClusterBuildCapture c;
    c.kind = CapturedCommandKind::kBuildAccelerationStructuresKhr;
    c.pause_id = pause;
    c.submission_index = index;
    c.command_buffer = cb;
    return c;
}

// Incompressible megabytes, in ranges apart from each other (not merged into one snapshot):
// more than the pipe and the compressor's queue hold, so the writer blocks on the FIFO.
void add_random_inputs(ClusterBuildCapture& c) {
    std::mt19937_64 random(23);
    for (uint64_t i = 0; i < kRanges; ++i) {
        std::vector<uint8_t> bytes(kRangeBytes);
        for (size_t at = 0; at < bytes.size(); at += 8) {
            const uint64_t v = random();
            std::memcpy(bytes.data() + at, &v, 8);
        }
        const uint64_t offset = i * 2 * kRangeBytes;
        CapturedRange r{MemoryRole::kBuildRanges, 0, kBufferAddress + offset, {}, kBuffer, offset};
        r.bytes = std::move(bytes);
        c.inputs.push_back(std::move(r));
    }
}

size_t bytes_in_pipe(int fd) {
    int n = 0;
    return ::ioctl(fd, FIONREAD, &n) == 0 ? size_t(n) : 0;
}

TEST(TraceSinkSlowWriter, NeitherABuildPastTheMemoryBoundNorAHostWriteWaitsForTheWriter) {
    const fs::path fifo = fs::temp_directory_path() /
                          ("clastrace_slow_writer_" + std::to_string(::getpid()) + ".clt");
    fs::remove(fifo);
    ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
    const int reader = ::open(fifo.c_str(), O_RDONLY | O_NONBLOCK);  // open, not read yet
    ASSERT_GE(reader, 0);
    const size_t pipe_bytes = size_t(::fcntl(reader, F_GETPIPE_SZ));

    std::string error;
    std::unique_ptr<CaptureSink> sink = make_trace_capture_sink(fifo.string(), 3, error, 0);
    ASSERT_TRUE(sink) << error;
    DeviceRecord device;
    device.device = 1;
    device.device_name = "test";
    sink->device_created(device);
    BufferRecord buffer;
    buffer.buffer = kBuffer;
    buffer.size = 2 * kRanges * kRangeBytes;
    sink->buffer_created(buffer);
    sink->buffer_bound({kBuffer, kMemory, 0});
    sink->buffer_address_queried({kBuffer, kBufferAddress});

    // Submission 1 with megabytes of snapshots; its flush blocks on the full pipe, holding the
    // writer's lock, until the test reads.
    submit_build(*sink, 1, 0x77, 3);
    ClusterBuildCapture first = captured_build(1, 0x77, 3);
    add_random_inputs(first);
    sink->cluster_build_captured(std::move(first));
    std::thread flusher([&] { sink->flush(); });
    // Full but for a page (the header's write left one partly used): the writer is blocked.
    while (bytes_in_pipe(reader) + size_t(::sysconf(_SC_PAGESIZE)) < pipe_bytes)
        std::this_thread::yield();

    // Submission 2: a host write ordered after it, then its build, held past the memory bound
    // (64 MiB; 300 MiB counted, no memory behind it), as the pause worker delivers it.
    submit_build(*sink, 2, 0x78, 4);
    const uint64_t waits_before = cost_total(CostPhase::kSinkBoundWait).count;
    std::atomic<bool> returned{false};
    std::thread deliverer([&] {
        mark_layer_thread();
        HostWriteRecord w;
        w.memory = kMemory;
        w.buffer = kBuffer;
        w.address = kBufferAddress;
        w.bytes = {1, 2, 3, 4};
        w.submission_index = 1;
        w.pause_id = 3;
        sink->host_write_observed(w);
        ClusterBuildCapture second = captured_build(2, 0x78, 4);
        second.held_bytes = 300ull << 20;
        sink->cluster_build_captured(std::move(second));
        returned = true;
    });
    // Nothing reads the pipe until the calls returned, so they cannot have waited for the
    // writer; the deadline only keeps a regression from hanging the suite (it then fails).
    const auto give_up = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (!returned && std::chrono::steady_clock::now() < give_up)
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
    EXPECT_TRUE(returned) << "the deliverer waited for the blocked writer";
    EXPECT_EQ(cost_total(CostPhase::kSinkBoundWait).count, waits_before);

    // Read everything: the flush ends, then the sink writes the rest as it is destroyed.
    ::fcntl(reader, F_SETFL, ::fcntl(reader, F_GETFL) & ~O_NONBLOCK);
    std::vector<char> stream;
    std::thread drain([&] {
        char block[65536];
        for (ssize_t n; (n = ::read(reader, block, sizeof block)) != 0;)
            if (n > 0) stream.insert(stream.end(), block, block + n);
    });
    flusher.join();
    deliverer.join();
    sink.reset();  // closes the write end: the drain sees the end of the stream
    drain.join();
    ::close(reader);
    fs::remove(fifo);

    // Both submissions are in the trace, the host write after the second (announced before it).
    const fs::path copy = fifo.string() + ".copy";
    std::ofstream(copy, std::ios::binary).write(stream.data(), std::streamsize(stream.size()));
    traces::TraceError read_error;
    auto trace = traces::TraceReader::open(copy.string(), &read_error);
    ASSERT_TRUE(trace) << read_error.message;
    traces::RecordView view;
    int submits = 0, observations = 0, observations_after_second = 0;
    while (trace->next(&view)) {
        if (view.kind == fbs::RecordBody::QueueSubmit) ++submits;
        if (view.kind == fbs::RecordBody::MemoryObservation) {
            ++observations;
            observations_after_second += submits == 2;
        }
    }
    fs::remove(copy);
    EXPECT_EQ(submits, 2);
    EXPECT_EQ(observations, 1);
    EXPECT_EQ(observations_after_second, 1);
}

}  // namespace
}  // namespace clastrace::capture
