// SPDX-License-Identifier: Apache-2.0
#include "clastrace/trace_building/record_writer.h"

#include "clastrace/trace_building/command_records.h"

#include <stdexcept>

namespace clastrace::trace_building {

void throw_if_error(const traces::TraceError& e) {
    if (e) throw std::runtime_error(e.message);
}

traces::TraceWriterOptions RecordWriter::quick() {
    traces::TraceWriterOptions o;
    o.sync_on_finish = false;
    return o;
}

RecordWriter::RecordWriter(const std::string& path, const fbs::TraceHeaderT& header,
                           traces::TraceWriterOptions options) {
    traces::TraceError e;
    writer_ = traces::TraceWriter::create(path, header, options, &e);
    throw_if_error(e);
}

void RecordWriter::append(const fbs::RecordT& r) { throw_if_error(writer_->append(r)); }

fbs::MemorySnapshot RecordWriter::snapshot(uint64_t address, const void* bytes, size_t size,
                                           uint64_t buffer, uint64_t offset) {
    fbs::MemorySnapshot s;
    throw_if_error(writer_->snapshot(buffer, offset, address, bytes, size, &s));
    return s;
}

void RecordWriter::buffer(uint64_t handle, uint64_t address, uint64_t size, uint64_t usage,
                          uint64_t memory, uint64_t memory_offset) {
    append(buffer_create(handle, size, usage));
    append(buffer_bind(handle, memory, memory_offset, address));
}

void RecordWriter::end_and_submit(uint64_t queue, uint64_t command_buffer, uint64_t fence) {
    append(command_buffer_end(command_buffer));
    append(queue_submit(queue, {command_buffer}, fence, next_submission_index()));
}

void RecordWriter::wait_fence(uint64_t fence) { append(fence_wait(fence)); }

traces::TraceWriterStats RecordWriter::finish() {
    throw_if_error(writer_->finish());
    return writer_->stats();
}

}  // namespace clastrace::trace_building
