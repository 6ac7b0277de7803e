// SPDX-License-Identifier: Apache-2.0
#include "sync_model_feed.h"

#include <algorithm>
#include <cstring>
#include <utility>

namespace clastrace::replay::detail {

SyncModelFeed::~SyncModelFeed() {
    if (!threaded()) return;
    {
        std::lock_guard lock(mutex_);
        stopping_ = true;
    }
    wake_worker_.notify_one();
    worker_.join();
}

void SyncModelFeed::start_thread() {
    if (threaded()) return;
    stopping_ = false;
    worker_ = std::thread([this] { work(); });
}

void SyncModelFeed::stop_thread() {
    if (!threaded()) return;
    drain();
    {
        std::lock_guard lock(mutex_);
        stopping_ = true;
    }
    wake_worker_.notify_one();
    worker_.join();
}

void SyncModelFeed::flush_open() {
    if (open_.calls.empty()) return;
    {
        std::unique_lock lock(mutex_);
        wake_replay_.wait(lock, [this] { return queued_.size() < kBatchesQueued; });
        queued_.push_back(std::move(open_));
    }
    open_ = Batch{};
    wake_worker_.notify_one();
}

void SyncModelFeed::drain() {
    if (!threaded()) return;
    flush_open();
    std::unique_lock lock(mutex_);
    wake_replay_.wait(lock, [this] { return queued_.empty() && !busy_; });
    if (failed_) std::rethrow_exception(std::exchange(failed_, nullptr));
}

// The worker takes one batch at a time; a call that throws is kept for drain() to rethrow and
// the calls after it are still applied (the replay thread decides what a failure means).
void SyncModelFeed::work() {
    std::unique_lock lock(mutex_);
    for (;;) {
        wake_worker_.wait(lock, [this] { return stopping_ || !queued_.empty(); });
        if (queued_.empty()) return;  // stopping, nothing left
        Batch batch = std::move(queued_.front());
        queued_.pop_front();
        busy_ = true;
        lock.unlock();
        wake_replay_.notify_one();  // room in the queue
        std::exception_ptr thrown;
        for (Call& call : batch.calls) {
            try {
                call(model_);
            } catch (...) {
                if (!thrown) thrown = std::current_exception();
            }
        }
        batch = Batch{};  // freed outside the lock
        lock.lock();
        busy_ = false;
        if (thrown && !failed_) failed_ = thrown;
        if (queued_.empty()) wake_replay_.notify_one();
    }
}

void SyncModelFeed::submit(Call call) {
    open_.calls.push_back(std::move(call));
    if (open_.calls.size() >= kCallsPerBatch) flush_open();
}

std::string_view SyncModelFeed::keep(std::string_view text) {
    if (text.empty()) return {};
    char* at = nullptr;
    if (text.size() > kTextBlock / 4) {  // a long text gets a block of its own
        at =
            open_.long_text.emplace_back(std::make_unique_for_overwrite<char[]>(text.size())).get();
    } else {
        if (open_.text.empty() || open_.text_used + text.size() > kTextBlock) {
            open_.text.push_back(std::make_unique_for_overwrite<char[]>(kTextBlock));
            open_.text_used = 0;
        }
        at = open_.text.back().get() + open_.text_used;
        open_.text_used += text.size();
    }
    std::memcpy(at, text.data(), text.size());
    return {at, text.size()};
}

// Each call: inline, straight to the model; threaded, a copy of its arguments in the batch.

void SyncModelFeed::begin_submission(QueueId queue, uint32_t submission_index,
                                     std::span<const SemaphoreWait> waits) {
    if (!threaded()) return model_.begin_submission(queue, submission_index, waits);
    submit([queue, submission_index, w = std::vector<SemaphoreWait>(waits.begin(), waits.end())](
               SyncModel& m) { m.begin_submission(queue, submission_index, w); });
}

void SyncModelFeed::record_access(const CommandRef& command, const Access& access) {
    if (!threaded()) return model_.record_access(command, access);
    submit([command, a = keep(access)](SyncModel& m) { m.record_access(command, a); });
}

void SyncModelFeed::record_accesses(const CommandRef& command, std::span<const Access> accesses) {
    if (!threaded()) return model_.record_accesses(command, accesses);
    std::vector<Access> kept;
    kept.reserve(accesses.size());
    for (const Access& a : accesses) kept.push_back(keep(a));
    submit([command, kept = std::move(kept)](SyncModel& m) { m.record_accesses(command, kept); });
}

void SyncModelFeed::record_accesses(const CommandRef& command, std::span<const Access> accesses,
                                    std::shared_ptr<const void> owner) {
    if (!threaded()) return model_.record_accesses(command, accesses);
    submit([command, accesses, owner = std::move(owner)](SyncModel& m) {
        m.record_accesses(command, accesses);
    });
}

void SyncModelFeed::record_copy(const CommandRef& command, const Access& source,
                                const Access& destination) {
    if (!threaded()) return model_.record_copy(command, source, destination);
    submit([command, s = keep(source), d = keep(destination)](SyncModel& m) {
        m.record_copy(command, s, d);
    });
}

void SyncModelFeed::record_deserialize(const CommandRef& command, const Access& source,
                                       const Access& destination) {
    if (!threaded()) return model_.record_deserialize(command, source, destination);
    submit([command, s = keep(source), d = keep(destination)](SyncModel& m) {
        m.record_deserialize(command, s, d);
    });
}

void SyncModelFeed::pipeline_barrier(const CommandRef& command, const DependencyInfo& dependency) {
    if (!threaded()) return model_.pipeline_barrier(command, dependency);
    submit([command, d = OwnedDependency(dependency)](SyncModel& m) {
        m.pipeline_barrier(command, d.view());
    });
}

void SyncModelFeed::set_event(const CommandRef& command, uint64_t event,
                              const DependencyInfo& dependency) {
    if (!threaded()) return model_.set_event(command, event, dependency);
    submit([command, event, d = OwnedDependency(dependency)](SyncModel& m) {
        m.set_event(command, event, d.view());
    });
}

void SyncModelFeed::set_event_v1(const CommandRef& command, uint64_t event,
                                 VkPipelineStageFlags stages) {
    if (!threaded()) return model_.set_event_v1(command, event, stages);
    submit([command, event, stages](SyncModel& m) { m.set_event_v1(command, event, stages); });
}

void SyncModelFeed::reset_event(const CommandRef& command, uint64_t event) {
    if (!threaded()) return model_.reset_event(command, event);
    submit([command, event](SyncModel& m) { m.reset_event(command, event); });
}

void SyncModelFeed::wait_events(const CommandRef& command, std::span<const uint64_t> events,
                                const DependencyInfo& dependency) {
    if (!threaded()) return model_.wait_events(command, events, dependency);
    submit(
        [command, e = std::vector<uint64_t>(events.begin(), events.end()),
         d = OwnedDependency(dependency)](SyncModel& m) { m.wait_events(command, e, d.view()); });
}

void SyncModelFeed::end_submission(std::span<const SemaphoreSignal> signals, uint64_t fence) {
    if (!threaded()) return model_.end_submission(signals, fence);
    submit([s = std::vector<SemaphoreSignal>(signals.begin(), signals.end()), fence](SyncModel& m) {
        m.end_submission(s, fence);
    });
}

void SyncModelFeed::host_access(const CommandRef& command, const Access& access) {
    if (!threaded()) return model_.host_access(command, access);
    submit([command, a = keep(access)](SyncModel& m) { m.host_access(command, a); });
}

void SyncModelFeed::wait_for_fence(uint64_t fence) {
    if (!threaded()) return model_.wait_for_fence(fence);
    submit([fence](SyncModel& m) { m.wait_for_fence(fence); });
}

void SyncModelFeed::queue_wait_idle(QueueId queue) {
    if (!threaded()) return model_.queue_wait_idle(queue);
    submit([queue](SyncModel& m) { m.queue_wait_idle(queue); });
}

void SyncModelFeed::device_wait_idle() {
    if (!threaded()) return model_.device_wait_idle();
    submit([](SyncModel& m) { m.device_wait_idle(); });
}

void SyncModelFeed::host_wait_semaphore(uint64_t semaphore, uint64_t value) {
    if (!threaded()) return model_.host_wait_semaphore(semaphore, value);
    submit([semaphore, value](SyncModel& m) { m.host_wait_semaphore(semaphore, value); });
}

void SyncModelFeed::host_signal_semaphore(uint64_t semaphore, uint64_t value) {
    if (!threaded()) return model_.host_signal_semaphore(semaphore, value);
    submit([semaphore, value](SyncModel& m) { m.host_signal_semaphore(semaphore, value); });
}

void SyncModelFeed::present_wait(std::span<const uint64_t> semaphores) {
    if (!threaded()) return model_.present_wait(semaphores);
    submit([s = std::vector<uint64_t>(semaphores.begin(), semaphores.end())](SyncModel& m) {
        m.present_wait(s);
    });
}

void SyncModelFeed::acquire_signal(uint64_t semaphore, uint64_t fence) {
    if (!threaded()) return model_.acquire_signal(semaphore, fence);
    submit([semaphore, fence](SyncModel& m) { m.acquire_signal(semaphore, fence); });
}

void SyncModelFeed::memory_freed(AddressRange range) {
    if (!threaded()) return model_.memory_freed(range);
    submit([range](SyncModel& m) { m.memory_freed(range); });
}

std::vector<HazardAccess> SyncModelFeed::pending_accesses(AddressRange range) {
    drain();
    return model_.pending_accesses(range);
}

const std::vector<HazardReport>& SyncModelFeed::hazards() {
    drain();
    return model_.hazards();
}

const SyncStats& SyncModelFeed::stats() {
    drain();
    return model_.stats();
}

}  // namespace clastrace::replay::detail
