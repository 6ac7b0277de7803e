// SPDX-License-Identifier: Apache-2.0
// The replayer's state, shared by the files that handle its record families (see
// replayer.cpp for the stream and the dispatch): replayer_memory_records.cpp (buffers,
// device memory, snapshots), replayer_acceleration_structures.cpp (objects, builds, checks),
// replayer_command_buffers.cpp (recording, executing, secondaries), replayer_queue_records.cpp
// (submissions, host waits, presentation), replayer_barriers.cpp (barriers and events),
// replayer_transfers.cpp (copies, fills, updates, dispatches) and replayer_hazard_merge.cpp.
#pragma once

#include "binary_signals.h"
#include "cluster_command.h"
#include "hazard_text.h"
#include "khr_command.h"
#include "nv_command.h"
#include "replayer_record_stage.h"
#include "replay_memory.h"
#include "structure_reachability.h"
#include "sync_consumers.h"
#include "sync_model_feed.h"

#include <clastrace/engine/execution_record.h>
#include <clastrace/engine/object_directory.h>
#include <clastrace/engine/properties.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/replay/sync_model.h>
#include <clastrace/traces/records.h>
#include <clastrace/traces/trace_reader.h>

#include <algorithm>
#include <cstdint>
#include <deque>
#include <map>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <tuple>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

namespace clastrace::replay::detail {

// Whether the sync model runs on a thread of its own: hazards checked on 2 threads or more, and
// ReplayOptions::sync_model_thread or CLASTRACE_REPLAY_SYNC_THREAD=1, or runs ahead on
// (`with_runs_ahead`) unless CLASTRACE_REPLAY_SYNC_THREAD=0.
bool model_on_own_thread(const ReplayOptions& options, bool with_runs_ahead);

namespace fbs = clastrace::fbs;
using traces::TraceReader;

constexpr uint64_t kWholeSize = ~0ull;  // VK_WHOLE_SIZE

// A command's place within its queue: (submission, command buffer, command) and, inside a
// secondary, (secondary, its command), since commands of one secondary share the primary's
// vkCmdExecuteCommands index.
inline auto command_place_key(const CommandRef& c) {
    return std::make_tuple(c.submission, c.command_buffer, c.command,
                           c.secondary_handle ? c.secondary + 1 : 0u, c.secondary_command);
}

// Hazards of one class between the same two commands over the same fields, told once
// (replayer_hazard_merge.cpp); *merged counts the reports folded into others.
std::vector<HazardReport> merge_per_op_hazards(const std::vector<HazardReport>& hazards,
                                               uint64_t* merged);

// "vkCmdTraceRaysKHR", ... as a static string (sync_consumers.cpp).
const char* trace_rays_entry_point(const fbs::CmdTraceRays& rays);

class Replay {
public:
    Replay(TraceReader& reader, const std::string& name, const ReplayOptions& options);

    ReplayReport run();

private:
    // A command's Record FlatBuffer, copied out of the reader, and (read ahead) the record
    // stage's answers for its snapshots: they go with the command to its turn, however many
    // records later (a submission) or how often (a buffer submitted again) that comes.
    struct RecordedCommand {
        std::vector<uint8_t> bytes;
        SnapshotAnswers answers{SnapshotAnswers::allocator_type(nullptr)};
    };
    using Commands = std::vector<RecordedCommand>;
    struct Recorded {
        Commands commands;
        // Restatements (format 1.2): restated[k - 1] is copy k of the recording, for the
        // (k+1)-th execution in the next submission that runs it (its own snapshots).
        std::vector<Commands> restated;
        uint32_t filling = 0;   // which copy the command records go to (0: commands)
        bool one_time = false;  // freed once submitted (memory stays bounded)
        bool secondary = false;
        uint64_t bytes = 0;
        uint64_t answer_bytes = 0;  // of its commands' answers (shared bytes counted each time)
        uint64_t submitted = 0;     // 1 + submission_index of its last submission, 0 never
        Commands& target() {
            return filling == 0 || filling > restated.size() ? commands : restated[filling - 1];
        }
        // The copy the `execution`-th execution (0-based) in a submission runs.
        const Commands& copy_for(uint32_t execution) const {
            return execution == 0 || execution > restated.size() ? commands
                                                                 : restated[execution - 1];
        }
    };

    void on_record(const traces::RecordView& view);
    // One record of the stream: the observer, the handlers, progress.
    void replay_record(const traces::RecordView& view, ReplayProgress& progress);
    // With 2 or more threads: reads records ahead of the one being replayed and starts their
    // cluster builds early (cluster_speculation.h, docs/replay.md "Threads").
    void replay_records_ahead(ReplayProgress& progress);
    // Read ahead (`read_ahead`) or at its own record, with the stage's answers for its
    // snapshots. A build read ahead whose buffers are not placed yet, or read while such a
    // build waits, waits in pending_runs_.
    void start_cluster_run(const traces::RecordView& view, std::span<const SnapshotAnswer> answers,
                           uint64_t stream_index, bool read_ahead);
    // Starts a run of the build; false when it has none. not_placed_yet (given read ahead):
    // see ClusterRunAhead::start.
    bool try_start_cluster_run(const traces::RecordView& view,
                               std::span<const SnapshotAnswer> answers, uint64_t stream_index,
                               bool* not_placed_yet);
    // Starts pending builds in stream order while the window has room, up to the first that
    // still names a buffer no region holds (tried again once regions were added); drops those
    // already replayed (they may start at their own record).
    void start_pending_runs();
    // The families of records on_record dispatches to; each returns whether it took the record.
    bool on_memory_record(fbs::RecordBody kind, const fbs::Record& r);
    bool on_acceleration_structure_record(fbs::RecordBody kind, const fbs::Record& r);
    bool on_command_buffer_record(fbs::RecordBody kind, const fbs::Record& r);
    bool on_queue_record(fbs::RecordBody kind, const fbs::Record& r);
    bool on_presentation_record(fbs::RecordBody kind, const fbs::Record& r);
    bool on_check_record(fbs::RecordBody kind, const fbs::Record& r);
    // VK_KHR_acceleration_structure's host records and commands (replayer_khr_records.cpp);
    // execute_khr_command returns whether the command was one of them.
    bool on_khr_record(fbs::RecordBody kind, const fbs::Record& r);
    bool execute_khr_command(const fbs::Record& record, const CommandRef& ref,
                             const ReplayLocation& where);
    // vkQueueBindSparse (replayer_sparse_binds.cpp).
    bool on_sparse_record(const traces::RecordView& view);
    // Applies a batch's buffer binds in order; a bind the replay cannot apply (damaged) or a
    // range bound twice in the batch is a finding naming the record `place`.
    void apply_sparse_binds(const fbs::SparseBindBatch& batch, QueueId queue,
                            const std::string& place);
    // The binds of one buffer bind entry that can be applied: checks the buffer and its
    // address; false (and a finding) when the whole entry must be skipped.
    bool sparse_buffer_usable(const fbs::SparseBufferBind& entry, QueueId queue,
                              const std::string& place);
    void sparse_bind_finding(const char* rule, QueueId queue, const std::string& message);
    // SyncModel's UnboundHandler: an access to a sparse buffer's unbound part is a finding.
    void unbound_access(const CommandRef& ref, QueueId queue, const Access& access,
                        AddressRange unbound);
    void record_command(const traces::RecordView& view);
    void on_submit(const fbs::QueueSubmit& submit);
    // Replays one execution of a command buffer (a primary listed in a batch, or a secondary
    // at its primary's vkCmdExecuteCommands: `inside` then names the execute command).
    void run_command_buffer(uint64_t handle, QueueId queue, uint32_t submission, uint32_t cb_index,
                            const CommandRef* inside);
    void execute_secondaries(const fbs::CmdExecuteCommands& execute, const CommandRef& ref,
                             QueueId queue);
    void reset_command_buffers(const fbs::CommandBufferReset& reset);
    // The command `ref` at `where` (location(ref, ...)).
    void execute_command(const fbs::Record& record, const CommandRef& ref,
                         const ReplayLocation& where);
    void replay_command(const fbs::Record& record, const CommandRef& ref,
                        const ReplayLocation& where, bool selected);
    void host_observation(const fbs::MemoryObservation& observation);

    // Memory helpers.
    bool contents(uint64_t hash, std::vector<uint8_t>* bytes);
    // A content's bytes without a copy, valid while `held` (the record stage's answer, when it
    // has one) is and until the next contents_view (the reader's view).
    bool contents_view(uint64_t hash, std::span<const uint8_t>* bytes, RecentContents::Bytes* held);
    void lay_in_snapshots(const traces::SnapshotVector* snapshots, const ReplayLocation& where);
    void feed(const CommandRef& ref, const AddressRange& range, StageMask stage, AccessMask access,
              bool write, std::string_view field);
    std::vector<BufferBarrier> buffer_barriers(const fbs::Dependency* dependency,
                                               std::vector<MemoryBarrier>* global);

    void copy_buffer(const fbs::CmdCopyBuffer& copy, const CommandRef& ref,
                     const ReplayLocation& where);
    void fill_buffer(const fbs::CmdFillBuffer& fill, const CommandRef& ref);
    void update_buffer(const fbs::CmdUpdateBuffer& update, const CommandRef& ref);
    // A dispatch or draw whose shaders (at `stages`, VkPipelineStageFlags2) may write through
    // buffer device addresses: a possible write of all device-address memory.
    void record_address_writes(const CommandRef& ref, uint64_t stages);
    void dispatch(const fbs::CmdDispatch& dispatch, const CommandRef& ref,
                  const ReplayLocation& where);
    // CLASTRACE_DEVICE_ADDRESS_WRITES=exact: a DeviceAddressWrites record, kept until the
    // dispatch it names runs (its submission's QueueSubmit follows it).
    void keep_exact_address_writes(const fbs::DeviceAddressWrites& writes);
    // The writes kept for the dispatch at `ref` (this execution), or nothing: then the trace
    // is a cheap one for it. Each is handed out once.
    std::optional<std::vector<fbs::MemorySnapshot>> take_exact_address_writes(
        const CommandRef& ref);
    // Feeds them as the dispatch's certain writes and lays their new bytes in memory.
    void record_exact_address_writes(const CommandRef& ref,
                                     const std::vector<fbs::MemorySnapshot>& writes);
    void build_clusters(const fbs::CmdBuildClusterAccelerationStructureIndirect& build,
                        const CommandRef& ref, const ReplayLocation& where);
    void build_nv(const fbs::CmdBuildAccelerationStructureNV& build, const CommandRef& ref,
                  const ReplayLocation& where);
    void copy_to_object(const fbs::CmdCopyMemoryToAccelerationStructure& copy,
                        const CommandRef& ref, const ReplayLocation& where);
    void barrier(const fbs::Record& record, const CommandRef& ref);

    // Consumers of acceleration structures (sync_consumers.cpp).
    using ConsumerBindings = flatbuffers::Vector<const fbs::AccelerationStructureBinding*>;
    void on_consumer_bookkeeping(fbs::RecordBody kind, const fbs::Record& r);
    void trace_rays(const fbs::CmdTraceRays& rays, const CommandRef& ref,
                    const ReplayLocation& where);
    void consumer_reads(const CommandRef& ref, const ConsumerBindings* bindings, StageMask stages,
                        const ReplayLocation& where);
    void note_top_level_build(const fbs::CmdBuildAccelerationStructureNV& build,
                              const ReplayLocation& where);
    void note_khr_top_level_builds(const fbs::CmdBuildAccelerationStructuresKHR& build,
                                   const ReplayLocation& where);
    std::vector<uint64_t> khr_instance_references(const fbs::GeometryInstancesKHR& instances,
                                                  const fbs::BuildRangeInfoKHR& range) const;
    // A destroy or free while a pending command still uses the bytes (sync_consumers.cpp).
    void check_commands_done(const AddressRange& range, const char* call, const char* rule,
                             const std::string& what_happens);
    // Structures read before any command built them (sync_unbuilt_structures.cpp).
    void note_structure_writes(const fbs::Record& record);
    std::string unbuilt_cause() const;
    std::string command_text(const ReplayLocation& where) const;
    void check_structure_built(const ReachedStructure& s, const std::string& reader,
                               const ReplayLocation& where);
    void check_consumer_structures_built(const ConsumerBindings* bindings,
                                         const ReplayLocation& where);
    void check_instances_built(uint64_t top, const ReplayLocation& where);
    std::optional<AddressRange> structure_range(uint64_t handle) const;
    std::optional<ClusterBottomLevel> cluster_bottom_level(uint64_t address) const;

    void add_finding(ReplayFinding finding);
    // VUID-vkQueueSubmit-pSignalSemaphores-00067 / VUID-vkQueueSubmit2-semaphore-03868 for one batch.
    void check_binary_signals(const fbs::QueueSubmit& submit, uint32_t batch,
                              std::span<const SemaphoreWait> waits,
                              std::span<const SemaphoreSignal> signals);
    void memory_freed(std::optional<AddressRange> range);
    void drop_recorded(const Recorded& cb) {
        recorded_bytes_ -= std::min(recorded_bytes_, cb.bytes);
        answer_bytes_ -= std::min(answer_bytes_, cb.answer_bytes);
    }
    // The answers of the record being replayed, for its command to keep (none past
    // kMaxAnswerBytes: its turn asks the reader then).
    SnapshotAnswers take_answers(Recorded& recorded);
    void limit_recorded();
    void forget_recorded(uint64_t handle) {
        if (auto it = recorded_.find(handle); it != recorded_.end()) {
            drop_recorded(it->second);
            recycle(it->second);
            recorded_.erase(it);
        }
    }
    // Takes the byte buffers of a recording being forgotten into spare_command_bytes_.
    void recycle(Recorded& cb);
    QueueId queue_id(uint64_t queue) {
        auto [it, inserted] = queues_.emplace(queue, static_cast<QueueId>(queues_.size()));
        return it->second;
    }
    bool selected(uint64_t sequence, uint32_t submission) const {
        if (options_.submission >= 0 && submission != static_cast<uint64_t>(options_.submission))
            return false;
        return sequence >= options_.first_command && sequence <= options_.last_command;
    }

    TraceReader& reader_;
    // Held by each call into the reader while the record stage reads it on its own thread.
    std::mutex reader_mutex_;
    ReplayOptions options_;
    ReplayReport report_;
    engine::EngineProperties properties_ = engine::EngineProperties::nvidia_default();
    engine::ObjectDirectory directory_;
    ReplayMemory memory_;
    SyncModel sync_model_;
    // Every call into the model goes through here: inline on one thread, else queued for the
    // model's own thread (sync_model_feed.h).
    SyncModelFeed sync_{sync_model_};
    detail::AddressTranslation translation_;
    std::unordered_map<uint64_t, Recorded> recorded_;
    // The byte buffers of forgotten recordings, for the commands recorded next: a frame mostly
    // records what the frame before did, so a command's copy mostly fits one without allocating.
    std::vector<std::vector<uint8_t>> spare_command_bytes_;
    static constexpr size_t kSpareCommandBuffers = 1024;
    static constexpr size_t kSpareCommandBufferBytes = 16 << 10;
    // Pool membership, as far as the trace tells it: resets that name both a command buffer
    // and its pool. vkResetCommandPool (pool only) then resets those buffers.
    std::unordered_map<uint64_t, std::unordered_set<uint64_t>> pool_members_;
    std::unordered_set<uint64_t>
        pools_noted_;  // pool resets of unknown membership already in not_replayed
    std::unordered_map<uint64_t, QueueId> queues_;
    detail::ClusterSizeQueries cluster_queries_;  // what build-size queries answered
    uint64_t sequence_ = 0;
    uint32_t next_submission_ = 0;
    uint32_t host_ops_ = 0;
    // Where run_cluster_command leaves the engine's record for options_.observer (null without one).
    engine::ExecutionRecord* observed_execution_ = nullptr;
    uint64_t* observed_engine_ns_ = nullptr;
    uint64_t recorded_bytes_ = 0;
    std::unordered_set<uint64_t> dropped_;  // command buffers limit_recorded() dropped
    // Executions so far of each command buffer in the submission being replayed (restatements).
    std::unordered_map<uint64_t, uint32_t> executions_;
    detail::BinarySignals binary_signals_;
    // DeviceAddressWrites by (submission, command buffer, command index), in record order (a
    // command buffer run twice in one submission has two); dropped at the end of the submission.
    std::map<std::tuple<uint32_t, uint64_t, uint32_t>, std::deque<std::vector<fbs::MemorySnapshot>>>
        exact_address_writes_;
    detail::NvReplay nv_{{memory_, report_, sync_, options_,
                          [this](ReplayFinding f) { add_finding(std::move(f)); },
                          [this](const traces::SnapshotVector* s, const ReplayLocation& w) {
                              lay_in_snapshots(s, w);
                          },
                          [this](engine::ExecutionRecord&& r, uint64_t ns) {
                              if (!observed_execution_) return;
                              *observed_execution_ = std::move(r);
                              *observed_engine_ns_ = ns;
                              observed_nv_ = true;
                          }}};
    bool observed_nv_ = false;  // the command in replay_command was an NV build or deserialization
    // Cluster builds started ahead of their turn (2 or more threads), the bytes of the command
    // being replayed (to find its run), and the stream index of the record being replayed. A
    // run's snapshots are the stage's answers for its record (session 15: before, the bytes of
    // the contents records read lately, a cache of its own).
    std::optional<RunAheadWindow> ahead_runs_;
    // The record stage's answers for the snapshots of the record or command being replayed
    // (replayer_record_stage.h), which contents() takes instead of asking the reader, and where
    // the next lookup starts: snapshots are asked for in the order the stage resolved them.
    struct CurrentAnswers {
        const SnapshotAnswers* list = nullptr;
        size_t next = 0;
    };
    CurrentAnswers answers_;
    SnapshotAnswers* staged_answers_ = nullptr;  // the record's, for its command to take
    // Answers the recorded commands hold, and the most they may (counted per command, so
    // bytes several commands share count more than once): a bound for traces that record much
    // and submit late; the bench's frames hold well under it.
    static constexpr uint64_t kMaxAnswerBytes = 32ull << 20;
    uint64_t answer_bytes_ = 0;
    const std::vector<uint8_t>* command_bytes_ = nullptr;
    uint64_t stream_index_ = 0;
    // Builds read ahead before the buffers they name were placed (a trace's first frames are
    // read ahead before its buffers are bound), and every build read after the first of them,
    // so that they start in stream order: started while they wait, they would find the window
    // full of later frames' runs at their own record and run on the replay thread in their
    // turn. Their views and answers point into the records read ahead, kept until replayed.
    struct PendingRun {
        traces::RecordView view;
        std::span<const SnapshotAnswer> answers;
        uint64_t stream_index = 0;
        uint64_t regions_added = UINT64_MAX;  // ReplayMemory::regions_added() when last tried
    };
    std::deque<PendingRun> pending_runs_;
    detail::KhrReplay khr_{{nv_, translation_}};  // KHR commands, on nv_'s objects (khr_command.h)
    // What consumers of acceleration structures reach, and the frames their hazards name.
    StructureReachability reachability_{[this](uint64_t handle) { return structure_range(handle); },
                                        [this](uint64_t address) {
                                            return cluster_bottom_level(address);
                                        }};
    std::unordered_map<uint64_t, uint8_t> structure_api_;  // handle -> 0 NV, 1 KHR
    FrameBoundaries frames_;
    // The trace's PreRangeState record, when it has one (format 1.5).
    struct PreRangeInfo {
        uint64_t before_frame = 0;
        uint64_t prelude_submission = 0;
    };
    std::optional<PreRangeInfo> pre_range_;
    std::unordered_set<uint64_t> unbuilt_told_;  // structures check_structure_built reported
};

}  // namespace clastrace::replay::detail
