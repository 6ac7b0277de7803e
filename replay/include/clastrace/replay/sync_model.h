// SPDX-License-Identifier: Apache-2.0
// SyncModel: decides which memory accesses of a captured stream are ordered and made
// visible by the spec's execution and memory dependencies, and reports those that are not.
//
// Feed it in execution order: one submission at a time (per-queue submission order, then
// command-buffer order, then command order), host operations between submissions where
// the trace has them. For each byte the model keeps the last write and the reads since,
// each with the dependency chains that reached it (the validation layers' per-resource
// access state, kept over device-address ranges instead of resources).
//
// Barriers are appended to a per-queue log and applied to an access's state only when a
// later access touches its bytes, so a global barrier costs O(1) however much memory is
// live. Host waits (fences, idle) complete accesses; they are swept out when the segments
// have doubled since the last sweep (always at idle waits), so memory stays within twice
// what is in flight, not growing with the trace.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <vector>

#include "clastrace/replay/hazard_report.h"
#include "clastrace/replay/sync_types.h"

namespace clastrace::replay {

struct SyncOptions {
    // Distinct hazards kept; later ones are only counted.
    std::size_t max_reports = 1000;
};

struct SyncStats {
    uint64_t accesses = 0;
    uint64_t barriers = 0;  // memory and buffer barriers, events and semaphore waits included
    uint64_t log_entries_applied = 0;  // lazy barrier applications (the model's main cost)
    uint64_t segments = 0;             // live address segments now
    uint64_t peak_segments = 0;
    uint64_t duplicate_hazards = 0;  // same command pair, class and fields as a kept report
    uint64_t hazards_over_cap = 0;   // hazards found once SyncOptions::max_reports were kept
    uint64_t unsatisfied_waits =
        0;  // semaphore waits with no signal seen yet (no ordering assumed)
    uint64_t event_slot_reuses = 0;  // >16 events pending at once: the oldest loses its ordering
    uint64_t visibility_spills =
        0;  // barrier applications leaving a write visible to >2 scopes (heap)
};

class SyncModel {
public:
    explicit SyncModel(SyncOptions options = {});
    ~SyncModel();
    SyncModel(const SyncModel&) = delete;
    SyncModel& operator=(const SyncModel&) = delete;

    // Accesses and buffer barriers go to the memory `resolver` maps their addresses to (null:
    // every address is its own memory). A part of an access with no memory bound is recorded
    // nowhere and given to `on_unbound` with the access, its queue and that part's addresses.
    using UnboundHandler =
        std::function<void(const CommandRef&, QueueId, const Access&, AddressRange unbound)>;
    void set_address_resolver(AddressResolver* resolver, UnboundHandler on_unbound);

    // --- device work, one submission batch at a time -------------------------------
    // Waits happen before the batch's commands (pWaitSemaphoreInfos / pWaitDstStageMask).
    void begin_submission(QueueId queue, uint32_t submission_index,
                          std::span<const SemaphoreWait> waits = {});
    void record_access(const CommandRef& command, const Access& access);
    // All accesses of one command, in the command's order: the same hazards, reported in the
    // same order and naming the same fields and ranges, as record_access on each in turn.
    // Cheaper for per-op arrays: accesses named "x[i]" (same text around the index, same
    // stage, access and direction, equal sizes, each starting where the one of i-1 ends) are
    // kept as one range, and a hazard on it is split back to the elements whose bytes meet.
    // Accesses overlapping another access of the command are recorded one by one, in order
    // (their order decides which of them a later command's hazard names).
    void record_accesses(const CommandRef& command, std::span<const Access> accesses);
    // A copy or move whose source and destination must not overlap (vkCmdCopyBuffer,
    // cluster moves with noMoveOverlap, AS copies): reports kMoveOverlap, then records both.
    void record_copy(const CommandRef& command, const Access& source, const Access& destination);
    // Deserialization (vkCmdCopyMemoryToAccelerationStructureKHR): write-after-read/write
    // hazards on the destination are reported as kDeserializeInUse.
    void record_deserialize(const CommandRef& command, const Access& source,
                            const Access& destination);
    void pipeline_barrier(const CommandRef& command, const DependencyInfo& dependency);
    // vkCmdSetEvent2 (dependency as given) or vkCmdSetEvent (v1: one barrier with the stage
    // mask and no access masks; the waiting command's barriers then supply the accesses).
    void set_event(const CommandRef& command, uint64_t event, const DependencyInfo& dependency);
    void set_event_v1(const CommandRef& command, uint64_t event, VkPipelineStageFlags stages);
    void reset_event(const CommandRef& command, uint64_t event);
    void wait_events(const CommandRef& command, std::span<const uint64_t> events,
                     const DependencyInfo& dependency);
    // Signals happen after the batch's commands; fence 0 means none.
    void end_submission(std::span<const SemaphoreSignal> signals = {}, uint64_t fence = 0);

    // --- host ----------------------------------------------------------------------
    // Host read or write of mapped memory (stage HOST, HOST_READ/HOST_WRITE set here).
    void host_access(const CommandRef& command, const Access& access);
    void wait_for_fence(uint64_t fence);
    void queue_wait_idle(QueueId queue);
    void device_wait_idle();
    void host_wait_semaphore(uint64_t semaphore, uint64_t value);
    // vkSignalSemaphore: satisfies device waits; orders only host work, which every later
    // submission sees anyway.
    void host_signal_semaphore(uint64_t semaphore, uint64_t value);
    // vkQueuePresentKHR: the presentation engine waits on binary semaphores and consumes their
    // signals (a later wait on one finds it unsignalled). It reads no memory the model tracks
    // and orders no later work, so nothing else changes.
    void present_wait(std::span<const uint64_t> semaphores);
    // vkAcquireNextImageKHR (successful): the presentation engine signals the binary semaphore
    // and the fence (0: none) from outside every queue, so a wait on either is satisfied but
    // orders nothing the model tracks (no memory is accessed).
    void acquire_signal(uint64_t semaphore, uint64_t fence);
    // vkDestroyBuffer / vkFreeMemory: forgets the completed accesses inside `range`.
    void memory_freed(AddressRange range);

    // Device accesses meeting `range` that no host wait has seen complete yet, one per command
    // and stage (sync_consumers.cpp): what vkDestroy* and vkFreeMemory must wait for.
    std::vector<HazardAccess> pending_accesses(AddressRange range) const;

    // --- results -------------------------------------------------------------------
    const std::vector<HazardReport>& hazards() const;
    const SyncStats& stats() const;
    // Bytes the model holds now (segments, records, logs); for the memory table.
    std::size_t memory_bytes() const;

private:
    struct State;
    std::unique_ptr<State> state_;
};

}  // namespace clastrace::replay
