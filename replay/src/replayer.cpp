// SPDX-License-Identifier: Apache-2.0
// replay_trace: streams the trace, queues each command buffer's commands until it is
// submitted, then executes them in submission order (see replayer.h).
// Each family of records has its handlers in its own file (replayer_internal.hpp lists them);
// this file keeps the public API, the stream and the dispatch.
#include "clastrace/replay/replayer.h"

#include "replayer_internal.h"

#include <tbb/global_control.h>
#include <tbb/info.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <memory>
#include <optional>
#include <string_view>

#include <chrono>

namespace clastrace::replay {

bool is_engine_device(const std::string& driver_name) {
    return driver_name.rfind("clastrace", 0) == 0;
}

namespace detail {
namespace {

// A BLAS build over cluster objects: it reads the CLAS runs read before it.
bool builds_bottom_level(const fbs::CmdBuildClusterAccelerationStructureIndirect& build) {
    return build.input() &&
           build.input()->op_type() ==
               VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV;
}

// A move of cluster objects: it reads the objects of the CLAS runs read before it.
bool moves_objects(const fbs::CmdBuildClusterAccelerationStructureIndirect& build) {
    return build.input() &&
           build.input()->op_type() == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV;
}

// A CLASTRACE_REPLAY_* switch: true for "1", false for "0", none when unset or anything else.
std::optional<bool> environment_switch(const char* variable) {
    const char* value = std::getenv(variable);
    if (!value) return std::nullopt;
    if (std::string_view(value) == "1") return true;
    if (std::string_view(value) == "0") return false;
    return std::nullopt;
}

}  // namespace

Replay::Replay(TraceReader& reader, const std::string& name, const ReplayOptions& options)
    : reader_(reader),
      options_(options),
      memory_(options.memory_budget_bytes),
      sync_model_(SyncOptions{options.max_findings}) {
    report_.trace = name;
    sync_model_.set_address_resolver(&memory_, [this](const CommandRef& ref, QueueId queue,
                                                      const Access& access, AddressRange unbound) {
        unbound_access(ref, queue, access, unbound);
    });
    report_.hazards_checked = options.check_hazards;
    report_.verified = options.verify_outputs;
    if (const fbs::TraceHeader* h = reader.header(); h && h->device()) {
        const fbs::DeviceInfo* d = h->device();
        if (d->name()) report_.device = d->name()->str();
        if (d->driver_name()) report_.engine_trace = is_engine_device(d->driver_name()->str());
        if (const fbs::ClusterProperties* p = d->cluster_properties()) {
            VkPhysicalDeviceClusterAccelerationStructurePropertiesNV vk{};
            vk.maxVerticesPerCluster = p->max_vertices_per_cluster();
            vk.maxTrianglesPerCluster = p->max_triangles_per_cluster();
            vk.clusterScratchByteAlignment = p->cluster_scratch_byte_alignment();
            vk.clusterByteAlignment = p->cluster_byte_alignment();
            vk.clusterTemplateByteAlignment = p->cluster_template_byte_alignment();
            vk.clusterBottomLevelByteAlignment = p->cluster_bottom_level_byte_alignment();
            vk.clusterTemplateBoundsByteAlignment = p->cluster_template_bounds_byte_alignment();
            vk.maxClusterGeometryIndex = p->max_cluster_geometry_index();
            properties_ = engine::EngineProperties::from_vk(vk);
        }
        nv_.set_device(*d);
    }
}

// Each record outside a command buffer goes to the handler of its family; the others are
// commands, kept in their command buffer until it is submitted.
void Replay::on_record(const traces::RecordView& view) {
    const fbs::Record& r = *view.record;
    const fbs::RecordBody kind = view.kind;
    on_consumer_bookkeeping(kind, r);  // before the families: a destroy checks what still reads
    if (on_memory_record(kind, r) || on_acceleration_structure_record(kind, r) ||
        on_command_buffer_record(kind, r) || on_queue_record(kind, r) ||
        on_presentation_record(kind, r) || on_check_record(kind, r) || on_khr_record(kind, r) ||
        on_sparse_record(view))
        return;
    record_command(view);
}

void Replay::execute_command(const fbs::Record& record, const CommandRef& ref,
                             const ReplayLocation& where) {
    ++report_.counts.commands;
    switch (record.body_type()) {
    case fbs::RecordBody::CmdPipelineBarrier:
    case fbs::RecordBody::CmdSetEvent:
    case fbs::RecordBody::CmdResetEvent:
    case fbs::RecordBody::CmdWaitEvents: barrier(record, ref); break;
    case fbs::RecordBody::CmdCopyBuffer:
        copy_buffer(*record.body_as_CmdCopyBuffer(), ref, where);
        break;
    case fbs::RecordBody::CmdFillBuffer: fill_buffer(*record.body_as_CmdFillBuffer(), ref); break;
    case fbs::RecordBody::CmdUpdateBuffer:
        update_buffer(*record.body_as_CmdUpdateBuffer(), ref);
        break;
    case fbs::RecordBody::CmdDispatch: {
        const fbs::CmdDispatch& d = *record.body_as_CmdDispatch();
        dispatch(d, ref, where);
        if (d.ray_query())
            consumer_reads(ref, d.acceleration_structures(), VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                           where);
        break;
    }
    case fbs::RecordBody::CmdDraw: {
        const fbs::CmdDraw& d = *record.body_as_CmdDraw();
        // A draw naming neither stage mask is a format 1.3 record: a draw that uses addresses.
        if (d.address_stages() || !d.ray_query_stages())
            record_address_writes(ref, d.address_stages());
        consumer_reads(ref, d.acceleration_structures(), d.ray_query_stages(), where);
        break;
    }
    case fbs::RecordBody::CmdTraceRays:
        trace_rays(*record.body_as_CmdTraceRays(), ref, where);
        break;
    case fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect:
        build_clusters(*record.body_as_CmdBuildClusterAccelerationStructureIndirect(), ref, where);
        break;
    case fbs::RecordBody::CmdBuildAccelerationStructureNV:
        build_nv(*record.body_as_CmdBuildAccelerationStructureNV(), ref, where);
        note_top_level_build(*record.body_as_CmdBuildAccelerationStructureNV(), where);
        break;
    case fbs::RecordBody::CmdCopyMemoryToAccelerationStructure:
        copy_to_object(*record.body_as_CmdCopyMemoryToAccelerationStructure(), ref, where);
        break;
    default:
        if (!execute_khr_command(record, ref, where))
            --report_.counts.commands;  // timestamps, labels: nothing to replay
        break;
    }
    // After the build ran (when replay runs it): what its top levels' instances name.
    if (record.body_type() == fbs::RecordBody::CmdBuildAccelerationStructuresKHR)
        note_khr_top_level_builds(*record.body_as_CmdBuildAccelerationStructuresKHR(), where);
}

// Executes (or skips) one command and, with an observer, hands it the command, then the
// findings and hazards the command produced.
void Replay::replay_command(const fbs::Record& record, const CommandRef& ref,
                            const ReplayLocation& where, bool selected) {
    ReplayObserver* observer = options_.observer;
    // Only an observer reads the model per command: that read drains the model's queue.
    const size_t findings = report_.findings.size(),
                 hazards = observer && options_.check_hazards ? sync_.hazards().size() : 0;
    const uint64_t engine_runs = report_.counts.cluster_commands;
    engine::ExecutionRecord execution;
    uint64_t engine_ns = 0;
    observed_nv_ = false;
    if (observer) {
        observed_execution_ = &execution;
        observed_engine_ns_ = &engine_ns;
    }
    const auto started = std::chrono::steady_clock::now();
    note_structure_writes(record);
    if (selected) {
        execute_command(record, ref, where);
    } else {
        ++report_.counts.skipped_commands;
    }
    if (!observer) return;
    observed_execution_ = nullptr;
    observed_engine_ns_ = nullptr;
    ReplayedCommand c{where,
                      &record,
                      selected,
                      report_.counts.cluster_commands != engine_runs || observed_nv_ ? &execution
                                                                                     : nullptr,
                      engine_ns,
                      static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                                std::chrono::steady_clock::now() - started)
                                                .count()),
                      &memory_.image(),
                      [this](uint64_t handle) { return nv_.built_shadow(handle); }};
    observer->on_command(c);
    for (size_t i = findings; i < report_.findings.size(); ++i)
        observer->on_finding(report_.findings[i]);
    if (options_.check_hazards)
        for (size_t i = hazards; i < sync_.hazards().size(); ++i)
            observer->on_hazard(sync_.hazards()[i]);
}

void Replay::add_finding(ReplayFinding finding) {
    // One place decides what is a limit of the replay: every caller reports through here.
    if (is_replay_limit(finding.rule)) {
        if (report_.notes.size() >= options_.max_findings) {
            ++report_.notes_over_cap;
            return;
        }
        report_.notes.push_back({std::move(finding.rule), std::move(finding.message), finding.where,
                                 finding.op_index, finding.address});
        return;
    }
    if (report_.findings.size() >= options_.max_findings) {
        ++report_.findings_over_cap;
        return;
    }
    report_.findings.push_back(std::move(finding));
}

void Replay::replay_record(const traces::RecordView& view, ReplayProgress& progress) {
    ++report_.counts.records;
    if (options_.observer) options_.observer->on_record(view);
    on_record(view);
    ++stream_index_;
    if (options_.progress && (report_.counts.records & 63) == 0) {
        progress.bytes_read = view.chunk_offset;
        progress.file_size = reader_.stats().file_size;
        progress.records = report_.counts.records;
        progress.commands = report_.counts.commands;
        options_.progress(progress);
    }
}

// Records are read into a queue of their own copies (at most kRecordsAhead records and
// kBytesAhead bytes, and no further while the window of runs is full); each cluster build read
// starts ahead, and the front record is replayed as always. The stage (replayer_record_stage.h)
// reads and copies them on a thread of its own.
void Replay::replay_records_ahead(ReplayProgress& progress) {
    constexpr size_t kRecordsAhead = 4096;
    constexpr uint64_t kBytesAhead = 16ull << 20;
    // The stage's answers the records ahead hold, counted per record (bytes several records
    // share count each time, so they hold less): a bound for snapshots far larger than records.
    constexpr uint64_t kAnswerBytesAhead = 64ull << 20;
    std::deque<StagedRecord> ahead;
    uint64_t ahead_bytes = 0, ahead_answer_bytes = 0, read = stream_index_;
    bool more = true;
    RecordStage stage(reader_, reader_mutex_);
    for (;;) {
        while (more && (ahead.empty() ||
                        (ahead.size() < kRecordsAhead && ahead_bytes < kBytesAhead &&
                         ahead_answer_bytes < kAnswerBytesAhead && !ahead_runs_->full()))) {
            StagedRecord& a = ahead.emplace_back();
            if (!stage.next(&a)) {
                ahead.pop_back();
                more = false;
                break;
            }
            ahead_bytes += a.view.size;
            ahead_answer_bytes += a.resolved_bytes;
            start_cluster_run(a.view, a.resolved, read++, true);
        }
        if (ahead.empty()) {
            pending_runs_.clear();  // their views pointed into `ahead`
            return;
        }
        StagedRecord front = std::move(ahead.front());
        ahead.pop_front();
        ahead_bytes -= front.view.size;
        ahead_answer_bytes -= front.resolved_bytes;
        answers_ = {&front.resolved, 0};
        staged_answers_ = &front.resolved;
        replay_record(front.view, progress);
        answers_ = {};
        staged_answers_ = nullptr;
        ahead_runs_->replayed_before(stream_index_);
        if (!pending_runs_.empty()) start_pending_runs();
    }
}

// With runs ahead, the record stage asked the reader already (its answer does not depend on
// when it is asked: the bytes it returns hash to the key); otherwise the reader answers, one
// caller at a time while the stage reads records on its own thread. The reader's view stays
// valid until its next read_contents_view, which only this thread makes: the stage's calls
// (next, read_contents) leave it be.
bool Replay::contents_view(uint64_t hash, std::span<const uint8_t>* bytes,
                           RecentContents::Bytes* held) {
    if (answers_.list)
        if (const RecentContents::Bytes* answer =
                find_answer(*answers_.list, &answers_.next, hash)) {
            *held = *answer;
            *bytes = **held;
            return true;
        }
    held->reset();
    std::lock_guard lock(reader_mutex_);
    return !reader_.read_contents_view(hash, bytes);
}

bool Replay::contents(uint64_t hash, std::vector<uint8_t>* bytes) {
    RecentContents::Bytes held;
    std::span<const uint8_t> view;
    if (!contents_view(hash, &view, &held)) return false;
    bytes->assign(view.begin(), view.end());
    return true;
}

// Read ahead, a build may name buffers whose records are not replayed yet: then it waits in
// pending_runs_ until they are placed, or starts when its own record is (record_command),
// which is still before its submission.
void Replay::start_cluster_run(const traces::RecordView& view,
                               std::span<const SnapshotAnswer> answers, uint64_t stream_index,
                               bool read_ahead) {
    const auto* build = view.record->body_as_CmdBuildClusterAccelerationStructureIndirect();
    if (!build) return;
    // Every BLAS record read bounds the CLAS runs the next BLAS (and a move after it) starts
    // on, started or not; a move record read keeps the runs it starts on until it starts.
    if (builds_bottom_level(*build)) ahead_runs_->note_bottom_level(stream_index);
    if (moves_objects(*build)) ahead_runs_->note_move(stream_index);
    if (read_ahead && !pending_runs_.empty()) {
        pending_runs_.push_back({view, answers, stream_index});  // after those read before it
        return;
    }
    bool not_placed_yet = false;
    if (!try_start_cluster_run(view, answers, stream_index,
                               read_ahead ? &not_placed_yet : nullptr) &&
        not_placed_yet)
        pending_runs_.push_back({view, answers, stream_index, memory_.regions_added()});
}

bool Replay::try_start_cluster_run(const traces::RecordView& view,
                                   std::span<const SnapshotAnswer> answers, uint64_t stream_index,
                                   bool* not_placed_yet) {
    if (ahead_runs_->full() || ahead_runs_->holds(stream_index)) return false;
    const auto& build = *view.record->body_as_CmdBuildClusterAccelerationStructureIndirect();
    const AheadInputs in{memory_,
                         answers,
                         cluster_queries_,
                         properties_,
                         ahead_runs_->storage(),
                         ahead_runs_->buffers(),
                         options_.max_findings_per_rule,
                         options_.check_hazards};
    std::vector<std::shared_ptr<ClusterRunAhead>> earlier;
    if (builds_bottom_level(build))
        earlier = ahead_runs_->builds_before(stream_index);
    else if (moves_objects(build))
        earlier = ahead_runs_->builds_for_move(stream_index);
    auto run = ClusterRunAhead::start({view.bytes, view.bytes + view.size}, stream_index, in,
                                      std::move(earlier), not_placed_yet);
    if (!run) return false;
    ++ahead_runs_->counts.started;
    ahead_runs_->add(std::move(run));
    return true;
}

void Replay::start_pending_runs() {
    while (!pending_runs_.empty() && pending_runs_.front().stream_index < stream_index_)
        pending_runs_.pop_front();  // replayed: its view is gone
    const uint64_t regions = memory_.regions_added();
    while (!pending_runs_.empty() && !ahead_runs_->full()) {
        // In stream order only: a later build started past one that waits for its buffers
        // would take its room in the window (the first frames' BLAS builds, whose destination
        // is bound after their CLAS builds' buffers, ran in their turn).
        PendingRun& first = pending_runs_.front();
        if (first.regions_added == regions) return;  // nothing placed since it was tried
        bool not_placed_yet = false;
        if (!try_start_cluster_run(first.view, first.answers, first.stream_index,
                                   &not_placed_yet) &&
            not_placed_yet) {
            first.regions_added = regions;
            return;
        }
        pending_runs_.pop_front();
    }
}

namespace {

// On 2 threads or more: CLASTRACE_REPLAY_RUN_AHEAD=0 or =1 when set, else
// ReplayOptions::run_ahead (on by default).
bool runs_ahead(const ReplayOptions& options) {
    if (replay_threads(options) < 2) return false;
    return environment_switch("CLASTRACE_REPLAY_RUN_AHEAD").value_or(options.run_ahead);
}

}  // namespace

// With builds run ahead, applying the model's calls is the largest part of what stays on the
// replay thread (docs/benchmarks.md, session 12 serial).
bool model_on_own_thread(const ReplayOptions& options, bool with_runs_ahead) {
    if (!options.check_hazards || replay_threads(options) < 2) return false;
    const std::optional<bool> asked = environment_switch("CLASTRACE_REPLAY_SYNC_THREAD");
    if (options.sync_model_thread || asked == true) return true;
    return with_runs_ahead && asked != false;
}

ReplayReport Replay::run() {
    traces::RecordView view;
    ReplayProgress progress;
    // On more than one thread, cluster builds run ahead unless told not to (ReplayOptions, or =0
    // in the environment; docs/replay.md "Threads"), and the sync model beside the replay with
    // them or when asked.
    const bool ahead = runs_ahead(options_);
    if (model_on_own_thread(options_, ahead)) sync_.start_thread();
    if (ahead) {
        ahead_runs_.emplace(std::min<size_t>(4 * size_t(replay_threads(options_)), 64));
        replay_records_ahead(progress);
        ahead_runs_->counts.most_images = ahead_runs_->storage().most_images();
        if (options_.run_ahead_counts) *options_.run_ahead_counts = ahead_runs_->counts;
        ahead_runs_.reset();
    } else {
        while (reader_.next(&view)) replay_record(view, progress);
    }
    for (const traces::TraceError& e : reader_.damage()) report_.trace_damage.push_back(e.message);
    for (const auto& [buffer, size] : memory_.over_budget())
        add_finding({"CLASTRACE-replay-memory-budget",
                     "buffer " + detail::hex(buffer) + " (" + std::to_string(size) +
                         " bytes) was left out of the replay's memory: the address space of all "
                         "buffers would exceed " +
                         std::to_string(ReplayMemory::kReservedLimit) + " bytes",
                     FindingSource::kReplay, ReplayLocation{}, -1, 0});
    if (memory_.writes_over_budget())
        add_finding({"CLASTRACE-replay-memory-budget",
                     std::to_string(memory_.writes_over_budget()) +
                         " write(s) to memory were refused: the replay's memory would hold more "
                         "than the budget of " +
                         std::to_string(options_.memory_budget_bytes) +
                         " bytes (ReplayOptions::memory_budget_bytes)",
                     FindingSource::kReplay, ReplayLocation{}, -1, 0});
    memory_.note_peak();
    report_.counts.peak_image_bytes = memory_.peak_resident_bytes();
    if (options_.check_hazards) {
        report_.hazards = merge_per_op_hazards(sync_.hazards(), &report_.hazards_merged);
        annotate_consumer_hazards(report_.hazards, frames_);
        report_.hazards_over_cap = sync_.stats().hazards_over_cap;
        report_.counts.unsatisfied_semaphore_waits = sync_.stats().unsatisfied_waits;
    }
    sync_.stop_thread();
    return std::move(report_);
}

}  // namespace detail

uint32_t replay_threads(const ReplayOptions& options) {
    if (options.threads != 0) return options.threads;
    return static_cast<uint32_t>(std::max(1, tbb::info::default_concurrency()));
}

// The engine's parallel loops run in the arena of the thread that calls them, so one arena of
// the chosen size bounds every parallel part of the replay; its one reserved slot is the
// calling thread, so an arena of 1 has no workers at all. TBB's process-wide worker limit
// starts at the machine's count: a larger request raises it for the replay's duration.
ReplayReport replay_trace(traces::TraceReader& reader, const std::string& trace_name,
                          const ReplayOptions& options) {
    detail::Replay replay(reader, trace_name, options);
    const uint32_t threads = replay_threads(options);
    std::unique_ptr<tbb::global_control> more_workers;
    if (threads > static_cast<uint32_t>(tbb::info::default_concurrency()))
        more_workers =
            std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                  threads);
    tbb::task_arena arena(static_cast<int>(threads));
    return arena.execute([&replay] { return replay.run(); });
}

}  // namespace clastrace::replay
