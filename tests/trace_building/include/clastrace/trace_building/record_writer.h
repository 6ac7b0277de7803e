// SPDX-License-Identifier: Apache-2.0
// A TraceWriter for traces that tests and benchmarks write by hand: every error throws
// std::runtime_error, so a trace that could not be written never reaches an assertion.
#pragma once

#include <clastrace/traces/trace_writer.h>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace clastrace::trace_building {

// Throws std::runtime_error with the error's message when `e` holds one.
void throw_if_error(const traces::TraceError& e);

// One record around `body` (any member of the RecordBody union).
template <class Body>
fbs::RecordT record(Body body) {
    fbs::RecordT r;
    r.body.Set(std::move(body));
    return r;
}

class RecordWriter {
public:
    // No fsync on finish: test traces are read back at once and thrown away.
    RecordWriter(const std::string& path, const fbs::TraceHeaderT& header,
                 traces::TraceWriterOptions options = quick());
    static traces::TraceWriterOptions quick();

    void append(const fbs::RecordT& r);
    template <class Body>
    void append(Body body) {
        append(record(std::move(body)));
    }
    // The bytes a command's capture saw at `address` (stored once per distinct content).
    fbs::MemorySnapshot snapshot(uint64_t address, const void* bytes, size_t size,
                                 uint64_t buffer = 0, uint64_t offset = 0);
    fbs::MemorySnapshot snapshot(uint64_t address, const std::vector<uint8_t>& bytes) {
        return snapshot(address, bytes.data(), bytes.size());
    }

    // vkCreateBuffer + vkBindBufferMemory; `address` 0: no device address.
    void buffer(uint64_t handle, uint64_t address, uint64_t size, uint64_t usage, uint64_t memory,
                uint64_t memory_offset);
    // vkQueueSubmit2 of one command buffer (ended first) with `fence`.
    void end_and_submit(uint64_t queue, uint64_t command_buffer, uint64_t fence);
    void wait_fence(uint64_t fence);

    uint64_t next_submission_index() const { return writer_->next_submission_index(); }
    traces::TraceWriter& writer() { return *writer_; }
    // Seals the file; returns what the writer stored.
    traces::TraceWriterStats finish();

private:
    std::unique_ptr<traces::TraceWriter> writer_;
};

}  // namespace clastrace::trace_building
