// SPDX-License-Identifier: Apache-2.0
// SyncModelFeed: the replay's one way into its SyncModel. Inline (the start), every call runs
// the model at once on the caller's thread. Threaded (start_thread), calls are copied into
// batches and applied in call order by a thread of the model's own, so the replay thread goes
// on with the next command meanwhile; every read of the model (hazards, stats, pending
// accesses) drains the queue first. The model sees the same calls in the same order either way,
// so its hazards and counts do not depend on the mode.
#pragma once

#include <clastrace/replay/sync_model.h>

#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <exception>
#include <functional>
#include <memory>
#include <mutex>
#include <span>
#include <string_view>
#include <thread>
#include <vector>

namespace clastrace::replay::detail {

class SyncModelFeed {
public:
    explicit SyncModelFeed(SyncModel& model) : model_(model) {}
    ~SyncModelFeed();
    SyncModelFeed(const SyncModelFeed&) = delete;
    SyncModelFeed& operator=(const SyncModelFeed&) = delete;

    // Starts the model's thread: calls are queued from now on.
    void start_thread();
    // Applies everything queued and joins the thread: calls run inline from now on. For what the
    // model calls back into the replay (the address resolver and its unbound handler) once that
    // may touch state the replay thread changes.
    void stop_thread();
    bool threaded() const { return worker_.joinable(); }
    // Waits until the model has applied every call made so far; rethrows what a call threw.
    void drain();

    // SyncModel's calls (sync_model.h), in the same order as given.
    void begin_submission(QueueId queue, uint32_t submission_index,
                          std::span<const SemaphoreWait> waits = {});
    void record_access(const CommandRef& command, const Access& access);
    void record_accesses(const CommandRef& command, std::span<const Access> accesses);
    // The same, for accesses that live in `owner` with the text their fields view: the feed
    // keeps `owner` with the call until the model applied it, instead of copying them.
    void record_accesses(const CommandRef& command, std::span<const Access> accesses,
                         std::shared_ptr<const void> owner);
    void record_copy(const CommandRef& command, const Access& source, const Access& destination);
    void record_deserialize(const CommandRef& command, const Access& source,
                            const Access& destination);
    void pipeline_barrier(const CommandRef& command, const DependencyInfo& dependency);
    void set_event(const CommandRef& command, uint64_t event, const DependencyInfo& dependency);
    void set_event_v1(const CommandRef& command, uint64_t event, VkPipelineStageFlags stages);
    void reset_event(const CommandRef& command, uint64_t event);
    void wait_events(const CommandRef& command, std::span<const uint64_t> events,
                     const DependencyInfo& dependency);
    void end_submission(std::span<const SemaphoreSignal> signals = {}, uint64_t fence = 0);
    void host_access(const CommandRef& command, const Access& access);
    void wait_for_fence(uint64_t fence);
    void queue_wait_idle(QueueId queue);
    void device_wait_idle();
    void host_wait_semaphore(uint64_t semaphore, uint64_t value);
    void host_signal_semaphore(uint64_t semaphore, uint64_t value);
    void present_wait(std::span<const uint64_t> semaphores);
    void acquire_signal(uint64_t semaphore, uint64_t fence);
    void memory_freed(AddressRange range);

    // Reads: drain first.
    std::vector<HazardAccess> pending_accesses(AddressRange range);
    const std::vector<HazardReport>& hazards();
    const SyncStats& stats();

private:
    using Call = std::function<void(SyncModel&)>;
    // Calls waiting for the model, with the text their accesses' fields view (Access::field is
    // a view; the caller's text may be gone by the time the model runs the call).
    struct Batch {
        std::vector<Call> calls;
        std::vector<std::unique_ptr<char[]>> text;  // blocks of kTextBlock, the last one filling
        size_t text_used = 0;
        std::vector<std::unique_ptr<char[]>> long_text;  // one block per text over kTextBlock / 4
    };
    static constexpr size_t kCallsPerBatch = 256;
    static constexpr size_t kBatchesQueued = 64;  // then the replay thread waits (memory bounded)
    static constexpr size_t kTextBlock = 16384;

    void submit(Call call);
    std::string_view keep(std::string_view text);
    Access keep(const Access& access) {
        Access copy = access;
        copy.field = keep(access.field);
        return copy;
    }
    // A dependency whose barriers live in the closure that applies it.
    struct OwnedDependency {
        std::vector<MemoryBarrier> memory;
        std::vector<BufferBarrier> buffers;
        uint32_t flags = 0;
        explicit OwnedDependency(const DependencyInfo& d)
            : memory(d.memory_barriers.begin(), d.memory_barriers.end()),
              buffers(d.buffer_barriers.begin(), d.buffer_barriers.end()),
              flags(d.dependency_flags) {}
        DependencyInfo view() const { return {memory, buffers, flags}; }
    };
    void flush_open();  // hands the open batch to the thread (mutex_ not held)
    void work();

    SyncModel& model_;
    Batch open_;  // filled by the replay thread only
    std::mutex mutex_;
    std::condition_variable wake_worker_, wake_replay_;
    std::deque<Batch> queued_;   // guarded by mutex_
    bool busy_ = false;          // the worker is applying a batch; guarded by mutex_
    bool stopping_ = false;      // guarded by mutex_
    std::exception_ptr failed_;  // the first call that threw; guarded by mutex_
    std::thread worker_;
};

}  // namespace clastrace::replay::detail
