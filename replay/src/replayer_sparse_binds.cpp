// SPDX-License-Identifier: Apache-2.0
// Sparse memory: vkQueueBindSparse binds memory under sparse buffers as a queue operation
// ordered like a submission batch; accesses through a sparse buffer reach the memory bound at
// the time they execute (ReplayMemory::resolve), and an access to a part with nothing bound is
// a finding.
#include "replayer_internal.h"

namespace clastrace::replay::detail {

namespace {

std::vector<SemaphoreWait> bind_waits(const fbs::SparseBindBatch& batch) {
    std::vector<SemaphoreWait> waits;
    if (batch.wait_semaphores())
        for (const fbs::SemaphoreOp* w : *batch.wait_semaphores())
            // VkBindSparseInfo has no wait stages: the binding waits as a whole.
            waits.push_back(
                {w->semaphore(), w->value(), StageMask(VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT)});
    return waits;
}

std::vector<SemaphoreSignal> bind_signals(const fbs::SparseBindBatch& batch) {
    std::vector<SemaphoreSignal> signals;
    if (batch.signal_semaphores())
        for (const fbs::SemaphoreOp* s : *batch.signal_semaphores())
            signals.push_back(
                {s->semaphore(), s->value(), StageMask(VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT)});
    return signals;
}

}  // namespace

bool Replay::on_sparse_record(fbs::RecordBody kind, const fbs::Record& r) {
    if (kind != fbs::RecordBody::QueueBindSparse) return false;
    const fbs::QueueBindSparse& bind = *r.body_as_QueueBindSparse();
    if (bind.result() != VK_SUCCESS || !bind.batches()) return true;  // nothing reached the queue
    const QueueId queue = queue_id(bind.queue());
    const size_t batch_count = bind.batches()->size();
    for (size_t b = 0; b < batch_count; ++b) {
        const fbs::SparseBindBatch& batch =
            *bind.batches()->Get(static_cast<flatbuffers::uoffset_t>(b));
        const std::vector<SemaphoreWait> waits = bind_waits(batch);
        const std::vector<SemaphoreSignal> signals = bind_signals(batch);
        for (const SemaphoreWait& w : waits)
            if (w.value == 0) binary_signals_.consume(w.semaphore);
        for (const SemaphoreSignal& s : signals)
            if (s.value == 0) binary_signals_.signal(s.semaphore, "vkQueueBindSparse");
        if (options_.check_hazards) sync_.begin_submission(queue, next_submission_, waits);
        apply_sparse_binds(batch);
        if (options_.check_hazards)
            sync_.end_submission(signals, b + 1 >= batch_count ? bind.fence() : 0);
    }
    return true;
}

void Replay::apply_sparse_binds(const fbs::SparseBindBatch& batch) {
    if (!batch.buffer_binds()) return;
    for (const fbs::SparseBufferBind* buffer : *batch.buffer_binds()) {
        if (!buffer->binds()) continue;
        for (const fbs::SparseMemoryBind* m : *buffer->binds())
            memory_.bind_sparse(buffer->buffer(), buffer->device_address(), m->resource_offset(),
                                m->size(), m->memory(), m->memory_offset());
    }
}

void Replay::unbound_access(const CommandRef& ref, const Access& access, AddressRange unbound) {
    std::string place = "addresses " + hex(unbound.begin) + ".." + hex(unbound.end);
    if (auto at = memory_.sparse_buffer_at(unbound.begin))
        place = "bytes [" + std::to_string(at->second) + ", " +
                std::to_string(at->second + (unbound.end - unbound.begin)) + ") of sparse buffer " +
                hex(at->first) + " (" + place + ")";
    const std::string field = access.field.empty() ? "" : std::string(access.field) + ": ";
    add_finding({"CLASTRACE-sparse-unbound-access",
                 field + (access.is_write ? "writes " : "reads ") + place +
                     ", where no memory is bound when the command executes (a buffer without "
                     "VK_BUFFER_CREATE_SPARSE_RESIDENCY_BIT must be fully bound before use; with "
                     "it, such reads are undefined and writes are discarded): bind the range with "
                     "vkQueueBindSparse, signalling a semaphore this submission waits on",
                 FindingSource::kReplay, location(ref, sequence_ ? sequence_ - 1 : 0), -1,
                 unbound.begin});
}

}  // namespace clastrace::replay::detail
