// SPDX-License-Identifier: Apache-2.0
// Sparse memory: vkQueueBindSparse binds memory under sparse buffers as a queue operation
// ordered like a submission batch; accesses through a sparse buffer reach the memory bound at
// the time they execute (ReplayMemory::resolve), and an access to a part with nothing bound is
// a finding.
#include "replayer_internal.h"

#include <clastrace/common/hex.h>

#include <algorithm>
#include <tuple>

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

// Rules of the binds themselves. A bind the replay cannot apply is damage (or a broken
// application); the spec forbids binding a range twice in one batch ("Within a batch, a given
// range of a resource must not be bound more than once", vkQueueBindSparse).
constexpr const char* kRuleBindDamaged = "CLASTRACE-sparse-bind-damaged";
constexpr const char* kRuleBoundTwice = "CLASTRACE-sparse-bind-overlap";
constexpr const char* kRuleBindBudget = "CLASTRACE-replay-sparse-bind-budget";
// Bound parts the replay keeps over all sparse buffers: 2^18 64 KiB pages are 16 GiB of
// pages bound one by one; a trace past that is hostile or beyond what the replay follows.
constexpr size_t kMaxSparseParts = size_t(1) << 18;

// Where a record lies in the file, for findings about one the replay cannot apply.
std::string record_place(const traces::RecordView& view) {
    return "QueueBindSparse record in chunk " + std::to_string(view.chunk_number) +
           " (file offset " + hex(view.chunk_offset) + ", frame at " + hex(view.raw_offset) +
           " of its decompressed bytes)";
}

// Why one VkSparseMemoryBind of a buffer of `buffer_size` bytes cannot be applied ("" when it
// can): the range must lie in the buffer and the memory range must not wrap.
std::string sparse_bind_problem(const fbs::SparseMemoryBind& m, uint64_t buffer_size) {
    const std::string range =
        "resourceOffset " + hex(m.resource_offset()) + " size " + hex(m.size());
    if (m.size() == 0) return range + ": size is 0";
    if (m.resource_offset() >= buffer_size || m.size() > buffer_size - m.resource_offset())
        return range + " runs past the buffer's " + hex(buffer_size) + " bytes";
    if (m.memory() != 0 && m.memory_offset() + m.size() < m.memory_offset())
        return "memoryOffset " + hex(m.memory_offset()) + " + size " + hex(m.size()) +
               " wraps past 2^64";
    return "";
}

struct BatchBind {  // one applied bind of a batch: a buffer's byte range, and which bind it was
    uint64_t buffer = 0;
    uint64_t begin = 0, end = 0;
    uint32_t entry = 0, bind = 0;
};

// The first range of a buffer that two binds of a batch both bind, described; nullopt if none.
std::optional<std::string> bound_twice(std::vector<BatchBind> binds) {
    std::sort(binds.begin(), binds.end(), [](const BatchBind& a, const BatchBind& b) {
        return std::tie(a.buffer, a.begin) < std::tie(b.buffer, b.begin);
    });
    for (size_t i = 1; i < binds.size(); ++i) {
        const BatchBind& a = binds[i - 1];
        const BatchBind& b = binds[i];
        if (a.buffer != b.buffer || b.begin >= a.end) continue;
        auto name = [](const BatchBind& x) {
            return "buffer bind " + std::to_string(x.entry) + " bind " + std::to_string(x.bind);
        };
        return name(a) + " and " + name(b) + " both bind bytes [" + hex(b.begin) + ", " +
               hex(std::min(a.end, b.end)) + ") of sparse buffer " + hex(a.buffer) +
               ", which a batch must not bind more than once (vkQueueBindSparse): the memory "
               "there is undefined; the replay keeps the later bind";
    }
    return std::nullopt;
}

}  // namespace

bool Replay::on_sparse_record(const traces::RecordView& view) {
    if (view.kind != fbs::RecordBody::QueueBindSparse) return false;
    const fbs::QueueBindSparse& bind = *view.record->body_as_QueueBindSparse();
    if (bind.result() != VK_SUCCESS || !bind.batches()) return true;  // nothing reached the queue
    // The model resolves addresses through the sparse binds (ReplayMemory::resolve) and reports
    // unbound parts as findings: from the first bind on it runs inline, in step with both.
    if (options_.check_hazards) sync_.stop_thread();
    const std::string place = record_place(view);
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
        apply_sparse_binds(batch, queue, place + ", batch " + std::to_string(b));
        if (options_.check_hazards)
            sync_.end_submission(signals, b + 1 >= batch_count ? bind.fence() : 0);
    }
    return true;
}

void Replay::apply_sparse_binds(const fbs::SparseBindBatch& batch, QueueId queue,
                                const std::string& place) {
    if (!batch.buffer_binds()) return;
    std::vector<BatchBind> applied;
    for (flatbuffers::uoffset_t e = 0; e < batch.buffer_binds()->size(); ++e) {
        const fbs::SparseBufferBind& entry = *batch.buffer_binds()->Get(e);
        const std::string entry_place =
            place + ", buffer bind " + std::to_string(e) + " (buffer " + hex(entry.buffer()) + ")";
        if (!entry.binds() || !sparse_buffer_usable(entry, queue, entry_place)) continue;
        const uint64_t buffer_size = memory_.buffer_extent(entry.buffer())->size;
        for (flatbuffers::uoffset_t k = 0; k < entry.binds()->size(); ++k) {
            const fbs::SparseMemoryBind& m = *entry.binds()->Get(k);
            const std::string problem = sparse_bind_problem(m, buffer_size);
            if (!problem.empty()) {
                sparse_bind_finding(kRuleBindDamaged, queue,
                                    entry_place + ", bind " + std::to_string(k) + ": " + problem +
                                        "; the bind is skipped");
                continue;
            }
            if (memory_.sparse_page_count() >= kMaxSparseParts) {
                sparse_bind_finding(kRuleBindBudget, queue,
                                    entry_place + ", bind " + std::to_string(k) +
                                        ": the sparse buffers already have " +
                                        std::to_string(kMaxSparseParts) +
                                        " bound parts, the replay's limit; this bind and the "
                                        "rest of the batch are not followed");
                return;
            }
            memory_.bind_sparse(entry.buffer(), entry.device_address(), m.resource_offset(),
                                m.size(), m.memory(), m.memory_offset());
            applied.push_back(
                {entry.buffer(), m.resource_offset(), m.resource_offset() + m.size(), e, k});
        }
    }
    if (const std::optional<std::string> twice = bound_twice(applied))
        sparse_bind_finding(kRuleBoundTwice, queue, place + ": " + *twice);
}

bool Replay::sparse_buffer_usable(const fbs::SparseBufferBind& entry, QueueId queue,
                                  const std::string& place) {
    const std::optional<ReplayMemory::BufferExtent> extent = memory_.buffer_extent(entry.buffer());
    std::string problem;
    const uint64_t address = entry.device_address();
    if (!extent) {
        problem = "no vkCreateBuffer of this buffer precedes the bind";
    } else if (extent->address && !memory_.meets_sparse_buffer(*extent->address, 1)) {
        problem = "the buffer is bound with vkBindBufferMemory, not a sparse buffer";
    } else if (extent->address && address != 0 && address != *extent->address) {
        problem = "device address " + hex(address) + " differs from " + hex(*extent->address) +
                  ", the address an earlier bind gave the buffer";
    } else if (!extent->address && address != 0 &&
               (address + extent->size < address ||
                address + extent->size > ReplayMemory::kPrivateBase)) {
        problem = "device address " + hex(address) + " + the buffer's size " + hex(extent->size) +
                  " runs past the device address space";
    } else if (!extent->address && address != 0 &&
               memory_.meets_sparse_buffer(address, extent->size)) {
        problem = "device addresses " + hex(address) + ".." + hex(address + extent->size) +
                  " overlap another sparse buffer's";
    }
    if (problem.empty()) return true;
    sparse_bind_finding(kRuleBindDamaged, queue,
                        place + ": " + problem + "; its binds are skipped");
    return false;
}

void Replay::sparse_bind_finding(const char* rule, QueueId queue, const std::string& message) {
    ReplayLocation where{sequence_, next_submission_, 0, 0, 0, "vkQueueBindSparse"};
    where.queue = queue;
    add_finding({rule, message, FindingSource::kReplay, where, -1, 0});
}

void Replay::unbound_access(const CommandRef& ref, QueueId queue, const Access& access,
                            AddressRange unbound) {
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
                 FindingSource::kReplay, location(ref, sequence_ ? sequence_ - 1 : 0, queue), -1,
                 unbound.begin});
}

}  // namespace clastrace::replay::detail
