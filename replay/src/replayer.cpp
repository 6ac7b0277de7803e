// replay_trace: streams the trace, queues each command buffer's commands until it is
// submitted, then executes them in submission order (see replayer.hpp).
#include "clastrace/replay/replayer.hpp"

#include "binary_signals.hpp"
#include "cluster_command.hpp"
#include "nv_command.hpp"
#include "replay_memory.hpp"

#include <clastrace/engine/execute.h>
#include <clastrace/engine/object_directory.h>
#include <clastrace/replay/sync_model.hpp>
#include <clastrace/traces/records.h>
#include <clastrace/traces/trace_reader.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <map>
#include <tuple>
#include <memory>
#include <unordered_map>
#include <unordered_set>

namespace clastrace::replay {

bool is_engine_device(const std::string& driver_name) { return driver_name.rfind("clastrace", 0) == 0; }

namespace {

using detail::ReplayMemory;
using traces::TraceReader;
namespace fbs = clastrace::fbs;

constexpr uint64_t kWholeSize = ~0ull;

const char* command_name(fbs::RecordBody kind) {
    switch (kind) {
    case fbs::RecordBody::CmdPipelineBarrier: return "vkCmdPipelineBarrier";
    case fbs::RecordBody::CmdSetEvent: return "vkCmdSetEvent";
    case fbs::RecordBody::CmdResetEvent: return "vkCmdResetEvent";
    case fbs::RecordBody::CmdWaitEvents: return "vkCmdWaitEvents";
    case fbs::RecordBody::CmdCopyBuffer: return "vkCmdCopyBuffer";
    case fbs::RecordBody::CmdFillBuffer: return "vkCmdFillBuffer";
    case fbs::RecordBody::CmdUpdateBuffer: return "vkCmdUpdateBuffer";
    case fbs::RecordBody::CmdDispatch: return "vkCmdDispatch";
    case fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect:
        return "vkCmdBuildClusterAccelerationStructureIndirectNV";
    case fbs::RecordBody::CmdBuildAccelerationStructureNV: return "vkCmdBuildAccelerationStructureNV";
    case fbs::RecordBody::CmdCopyMemoryToAccelerationStructure: return "vkCmdCopyMemoryToAccelerationStructureKHR";
    case fbs::RecordBody::GpuTimestamp: return "vkCmdWriteTimestamp";
    case fbs::RecordBody::DebugLabel: return "vkCmdDebugUtilsLabelEXT";
    case fbs::RecordBody::CmdExecuteCommands: return "vkCmdExecuteCommands";
    default: return "command";
    }
}

uint64_t command_buffer_of(const fbs::Record& r) {
    switch (r.body_type()) {
    case fbs::RecordBody::CmdPipelineBarrier: return r.body_as_CmdPipelineBarrier()->command_buffer();
    case fbs::RecordBody::CmdSetEvent: return r.body_as_CmdSetEvent()->command_buffer();
    case fbs::RecordBody::CmdResetEvent: return r.body_as_CmdResetEvent()->command_buffer();
    case fbs::RecordBody::CmdWaitEvents: return r.body_as_CmdWaitEvents()->command_buffer();
    case fbs::RecordBody::CmdCopyBuffer: return r.body_as_CmdCopyBuffer()->command_buffer();
    case fbs::RecordBody::CmdFillBuffer: return r.body_as_CmdFillBuffer()->command_buffer();
    case fbs::RecordBody::CmdUpdateBuffer: return r.body_as_CmdUpdateBuffer()->command_buffer();
    case fbs::RecordBody::CmdDispatch: return r.body_as_CmdDispatch()->command_buffer();
    case fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect:
        return r.body_as_CmdBuildClusterAccelerationStructureIndirect()->command_buffer();
    case fbs::RecordBody::CmdBuildAccelerationStructureNV:
        return r.body_as_CmdBuildAccelerationStructureNV()->command_buffer();
    case fbs::RecordBody::CmdCopyMemoryToAccelerationStructure:
        return r.body_as_CmdCopyMemoryToAccelerationStructure()->command_buffer();
    case fbs::RecordBody::GpuTimestamp: return r.body_as_GpuTimestamp()->command_buffer();
    case fbs::RecordBody::DebugLabel: return r.body_as_DebugLabel()->command_buffer();
    case fbs::RecordBody::CmdExecuteCommands: return r.body_as_CmdExecuteCommands()->command_buffer();
    default: return 0;
    }
}

// "srcInfosArray[3].vertexBuffer" -> "srcInfosArray[*].vertexBuffer",
// "dstImplicitData[op 3]" -> "dstImplicitData[op *]".
std::string any_index(const std::string& field) {
    std::string out;
    for (size_t i = 0; i < field.size(); ++i) {
        out += field[i];
        if (field[i] != '[') continue;
        if (field.compare(i + 1, 3, "op ") == 0) {
            out += "op ";
            i += 3;
        }
        size_t j = i + 1;
        while (j < field.size() && field[j] >= '0' && field[j] <= '9') ++j;
        if (j > i + 1 && j < field.size() && field[j] == ']') {
            out += '*';
            i = j - 1;
        }
    }
    return out;
}

// The engine reports accesses per op, so one missing barrier before a build would show
// once per op. Hazards of one class between the same two commands over the same prior
// field become one report whose later field names the ops as [*] and whose ranges cover them all.
std::vector<HazardReport> merge_per_op_hazards(const std::vector<HazardReport>& hazards, uint64_t* merged) {
    std::vector<HazardReport> out;
    // A command is (submission, command buffer, command) and, inside a secondary, (secondary,
    // its command): commands of one secondary share the primary's execute index.
    auto command_key = [](const CommandRef& c) {
        return std::make_tuple(c.submission, c.command_buffer, c.command, c.secondary_handle ? c.secondary + 1 : 0u,
                               c.secondary_command);
    };
    using CommandKey = decltype(command_key(CommandRef{}));
    std::map<std::tuple<int, CommandKey, CommandKey, std::string, std::string>, size_t> index;
    for (const HazardReport& h : hazards) {
        auto key = std::make_tuple(int(h.hazard), command_key(h.prior.command), command_key(h.later.command),
                                   any_index(h.prior.field), any_index(h.later.field));
        auto [it, inserted] = index.emplace(key, out.size());
        if (inserted) {
            out.push_back(h);
            continue;
        }
        ++*merged;
        HazardReport& m = out[it->second];
        if (m.later.field != h.later.field) m.later.field = std::get<4>(key);
        if (m.prior.field != h.prior.field) m.prior.field = std::get<3>(key);
        m.later.range = {std::min(m.later.range.begin, h.later.range.begin), std::max(m.later.range.end, h.later.range.end)};
        m.prior.range = {std::min(m.prior.range.begin, h.prior.range.begin), std::max(m.prior.range.end, h.prior.range.end)};
        m.overlap = {std::min(m.overlap.begin, h.overlap.begin), std::max(m.overlap.end, h.overlap.end)};
    }
    return out;
}

class Replay {
public:
    Replay(TraceReader& reader, const std::string& name, const ReplayOptions& options)
        : reader_(reader), options_(options), memory_(options.memory_budget_bytes), sync_(SyncOptions{options.max_findings}) {
        report_.trace = name;
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

    ReplayReport run();

private:
    using Commands = std::vector<std::vector<uint8_t>>;  // Record FlatBuffers, copied out of the reader
    struct Recorded {
        Commands commands;
        // Restatements (format 1.2): restated[k - 1] is copy k of the recording, for the
        // (k+1)-th execution in the next submission that runs it (its own snapshots).
        std::vector<Commands> restated;
        uint32_t filling = 0;                         // which copy the command records go to (0: commands)
        bool one_time = false;                        // freed once submitted (memory stays bounded)
        bool secondary = false;
        uint64_t bytes = 0;
        uint64_t submitted = 0;                       // 1 + submission_index of its last submission, 0 never
        Commands& target() { return filling == 0 || filling > restated.size() ? commands : restated[filling - 1]; }
        // The copy the `execution`-th execution (0-based) in a submission runs.
        const Commands& copy_for(uint32_t execution) const {
            return execution == 0 || execution > restated.size() ? commands : restated[execution - 1];
        }
    };

    void on_record(const traces::RecordView& view);
    // The families of records on_record dispatches to; each returns whether it took the record.
    bool on_memory_record(fbs::RecordBody kind, const fbs::Record& r);
    bool on_acceleration_structure_record(fbs::RecordBody kind, const fbs::Record& r);
    bool on_command_buffer_record(fbs::RecordBody kind, const fbs::Record& r);
    bool on_queue_record(fbs::RecordBody kind, const fbs::Record& r);
    bool on_presentation_record(fbs::RecordBody kind, const fbs::Record& r);
    bool on_check_record(fbs::RecordBody kind, const fbs::Record& r);
    void record_command(const traces::RecordView& view);
    void on_submit(const fbs::QueueSubmit& submit);
    // Replays one execution of a command buffer (a primary listed in a batch, or a secondary
    // at its primary's vkCmdExecuteCommands: `inside` then names the execute command).
    void run_command_buffer(uint64_t handle, uint32_t submission, uint32_t cb_index, const CommandRef* inside);
    void execute_secondaries(const fbs::CmdExecuteCommands& execute, const CommandRef& ref);
    void reset_command_buffers(const fbs::CommandBufferReset& reset);
    void execute_command(const fbs::Record& record, const CommandRef& ref, uint64_t sequence);
    void replay_command(const fbs::Record& record, const CommandRef& ref, uint64_t sequence, bool selected);
    void host_observation(const fbs::MemoryObservation& observation);

    // Memory helpers.
    bool contents(uint64_t hash, std::vector<uint8_t>* bytes);
    void lay_in_snapshots(const traces::SnapshotVector* snapshots, const ReplayLocation& where);
    void feed(const CommandRef& ref, const AddressRange& range, StageMask stage, AccessMask access, bool write,
              std::string_view field);
    std::vector<BufferBarrier> buffer_barriers(const fbs::Dependency* dependency, std::vector<MemoryBarrier>* global);

    void copy_buffer(const fbs::CmdCopyBuffer& copy, const CommandRef& ref, const ReplayLocation& where);
    void fill_buffer(const fbs::CmdFillBuffer& fill, const CommandRef& ref);
    void update_buffer(const fbs::CmdUpdateBuffer& update, const CommandRef& ref);
    void dispatch(const fbs::CmdDispatch& dispatch, const CommandRef& ref, const ReplayLocation& where);
    void build_nv(const fbs::CmdBuildAccelerationStructureNV& build, const CommandRef& ref, const ReplayLocation& where);
    void copy_to_object(const fbs::CmdCopyMemoryToAccelerationStructure& copy, const CommandRef& ref,
                        const ReplayLocation& where);
    void barrier(const fbs::Record& record, const CommandRef& ref);

    void add_finding(ReplayFinding finding);
    // VUID-vkQueueSubmit-pSignalSemaphores-00067 / VUID-vkQueueSubmit2-semaphore-03868 for one batch.
    void check_binary_signals(const fbs::QueueSubmit& submit, uint32_t batch, std::span<const SemaphoreWait> waits,
                              std::span<const SemaphoreSignal> signals);
    void memory_freed(std::optional<AddressRange> range);
    void drop_recorded(const Recorded& cb) { recorded_bytes_ -= std::min(recorded_bytes_, cb.bytes); }
    void limit_recorded();
    void forget_recorded(uint64_t handle) {
        if (auto it = recorded_.find(handle); it != recorded_.end()) {
            drop_recorded(it->second);
            recorded_.erase(it);
        }
    }
    ReplayLocation location(const CommandRef& ref, uint64_t sequence) const {
        return ReplayLocation{sequence,  ref.submission,       ref.command_buffer, ref.command, ref.command_buffer_handle,
                              ref.name,  ref.secondary_handle, ref.secondary,      ref.secondary_command};
    }
    QueueId queue_id(uint64_t queue) {
        auto [it, inserted] = queues_.emplace(queue, static_cast<QueueId>(queues_.size()));
        return it->second;
    }
    bool selected(uint64_t sequence, uint32_t submission) const {
        if (options_.submission >= 0 && submission != static_cast<uint64_t>(options_.submission)) return false;
        return sequence >= options_.first_command && sequence <= options_.last_command;
    }

    TraceReader& reader_;
    ReplayOptions options_;
    ReplayReport report_;
    engine::EngineProperties properties_ = engine::EngineProperties::nvidia_default();
    engine::ObjectDirectory directory_;
    ReplayMemory memory_;
    SyncModel sync_;
    detail::AddressTranslation translation_;
    std::unordered_map<uint64_t, Recorded> recorded_;
    // Pool membership, as far as the trace tells it: resets that name both a command buffer
    // and its pool. vkResetCommandPool (pool only) then resets those buffers.
    std::unordered_map<uint64_t, std::unordered_set<uint64_t>> pool_members_;
    std::unordered_set<uint64_t> pools_noted_;  // pool resets of unknown membership already in not_replayed
    std::unordered_map<uint64_t, QueueId> queues_;
    std::map<std::pair<uint32_t, uint32_t>, uint32_t> queried_max_count_;  // (opType, opMode) -> count
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
    detail::NvReplay nv_{{memory_, report_, sync_, options_, [this](ReplayFinding f) { add_finding(std::move(f)); },
                          [this](const traces::SnapshotVector* s, const ReplayLocation& w) { lay_in_snapshots(s, w); },
                          [this](engine::ExecutionRecord&& r, uint64_t ns) {
                              if (!observed_execution_) return;
                              *observed_execution_ = std::move(r);
                              *observed_engine_ns_ = ns;
                              observed_nv_ = true;
                          }}};
    bool observed_nv_ = false;  // the command in replay_command was an NV build or deserialization
};

// Executes (or skips) one command and, with an observer, hands it the command, then the
// findings and hazards the command produced.
void Replay::replay_command(const fbs::Record& record, const CommandRef& ref, uint64_t sequence, bool selected) {
    ReplayObserver* observer = options_.observer;
    const size_t findings = report_.findings.size(), hazards = options_.check_hazards ? sync_.hazards().size() : 0;
    const uint64_t engine_runs = report_.counts.cluster_commands;
    engine::ExecutionRecord execution;
    uint64_t engine_ns = 0;
    observed_nv_ = false;
    if (observer) {
        observed_execution_ = &execution;
        observed_engine_ns_ = &engine_ns;
    }
    const auto started = std::chrono::steady_clock::now();
    if (selected) {
        execute_command(record, ref, sequence);
    } else {
        ++report_.counts.skipped_commands;
    }
    if (!observer) return;
    observed_execution_ = nullptr;
    observed_engine_ns_ = nullptr;
    ReplayedCommand c{location(ref, sequence), &record, selected,
                      report_.counts.cluster_commands != engine_runs || observed_nv_ ? &execution : nullptr, engine_ns,
                      static_cast<uint64_t>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                                std::chrono::steady_clock::now() - started).count()),
                      &memory_.image()};
    observer->on_command(c);
    for (size_t i = findings; i < report_.findings.size(); ++i) observer->on_finding(report_.findings[i]);
    if (options_.check_hazards)
        for (size_t i = hazards; i < sync_.hazards().size(); ++i) observer->on_hazard(sync_.hazards()[i]);
}

// A destroyed buffer's memory: nothing the replay keeps about those bytes can matter to a
// later command except accesses still in flight (the sync model keeps those).
void Replay::memory_freed(std::optional<AddressRange> range) {
    if (!range || range->empty()) return;
    directory_.forget(range->begin, range->end);
    auto inside = [&](uint64_t a) { return a >= range->begin && a < range->end; };
    std::erase_if(translation_.rebuilt, inside);
    std::erase_if(translation_.rebuilt_at, [&](const auto& e) { return inside(e.first) || inside(e.second); });
    std::erase_if(translation_.translated_cells, [&](const auto& e) { return inside(e.first); });
    if (options_.check_hazards) sync_.memory_freed(*range);
}

// Command buffers stay recorded after submission because they may be submitted again;
// captures rarely say when one is freed, so past the limit the least recently submitted go.
void Replay::limit_recorded() {
    if (recorded_bytes_ <= options_.max_recorded_bytes) return;
    std::vector<std::pair<uint64_t, uint64_t>> submitted;  // (submitted, handle)
    for (const auto& [handle, cb] : recorded_)
        if (cb.submitted) submitted.emplace_back(cb.submitted, handle);
    std::sort(submitted.begin(), submitted.end());
    for (const auto& [when, handle] : submitted) {
        if (recorded_bytes_ <= options_.max_recorded_bytes / 2) break;
        drop_recorded(recorded_[handle]);
        recorded_.erase(handle);
        if (dropped_.size() < (1u << 16)) dropped_.insert(handle);
    }
}

void Replay::add_finding(ReplayFinding finding) {
    if (report_.findings.size() >= options_.max_findings) {
        ++report_.findings_over_cap;
        return;
    }
    report_.findings.push_back(std::move(finding));
}

bool Replay::contents(uint64_t hash, std::vector<uint8_t>* bytes) {
    return !reader_.read_contents(hash, bytes);
}

void Replay::lay_in_snapshots(const traces::SnapshotVector* snapshots, const ReplayLocation& where) {
    if (!snapshots) return;
    std::vector<uint8_t> bytes;
    for (const fbs::MemorySnapshot* s : *snapshots) {
        std::optional<uint64_t> address = memory_.snapshot_address(s->buffer(), s->offset(), s->address());
        const uint64_t refused = memory_.writes_over_budget();
        if (!address || !contents(s->hash(), &bytes) || !memory_.lay_in(*address, bytes)) {
            ++report_.counts.snapshots_outside_memory;
            if (memory_.writes_over_budget() != refused) continue;  // named once, by the budget finding
            add_finding({"CLASTRACE-replay-snapshot-outside-memory",
                         "captured snapshot of " + std::to_string(s->size()) + " bytes at buffer " +
                             detail::hex(s->buffer()) + " offset " + std::to_string(s->offset()) + " address " +
                             detail::hex(s->address()) +
                             " lies in no bound buffer (or its contents are missing): not laid into memory",
                         FindingSource::kReplay, where, -1, s->address()});
            continue;
        }
        ++report_.counts.snapshots_applied;
        report_.counts.snapshot_bytes += bytes.size();
    }
}

void Replay::feed(const CommandRef& ref, const AddressRange& range, StageMask stage, AccessMask access, bool write,
                  std::string_view field) {
    if (!options_.check_hazards || range.empty()) return;
    ++report_.counts.accesses;
    sync_.record_access(ref, Access{range, stage, access, write, field});
}

void Replay::host_observation(const fbs::MemoryObservation& observation) {
    if (!observation.snapshots()) return;
    CommandRef ref{next_submission_, 0, 0, host_ops_++, "host write (mapped memory)"};
    std::vector<uint8_t> bytes, before;
    for (const fbs::MemorySnapshot* s : *observation.snapshots()) {
        std::optional<uint64_t> address = memory_.snapshot_address(s->buffer(), s->offset(), s->address());
        if (!address || !contents(s->hash(), &bytes)) {
            ++report_.counts.snapshots_outside_memory;
            continue;
        }
        // A capture may observe mapped memory the host did not touch: only bytes that
        // changed count as a host write (unchanged ones would be false WAR/WAW hazards).
        AddressRange written{*address, *address + bytes.size()};
        if (memory_.read(*address, bytes.size(), &before)) {
            size_t first = 0, last = bytes.size();
            while (first < last && bytes[first] == before[first]) ++first;
            while (last > first && bytes[last - 1] == before[last - 1]) --last;
            written = {*address + first, *address + last};
        }
        if (!memory_.write(*address, bytes)) {
            ++report_.counts.snapshots_outside_memory;
            continue;
        }
        ++report_.counts.snapshots_applied;
        report_.counts.snapshot_bytes += bytes.size();
        if (options_.check_hazards && !written.empty()) {
            ++report_.counts.accesses;
            sync_.host_access(ref, Access{written, VK_PIPELINE_STAGE_2_HOST_BIT, VK_ACCESS_2_HOST_WRITE_BIT, true,
                                          "mapped memory"});
        }
    }
}

std::vector<BufferBarrier> Replay::buffer_barriers(const fbs::Dependency* dependency, std::vector<MemoryBarrier>* global) {
    std::vector<BufferBarrier> out;
    if (!dependency) return out;
    if (dependency->memory_barriers()) {
        for (const fbs::MemoryBarrier* b : *dependency->memory_barriers())
            global->push_back({b->src_stage_mask(), b->src_access_mask(), b->dst_stage_mask(), b->dst_access_mask()});
    }
    if (dependency->buffer_barriers()) {
        for (const fbs::BufferMemoryBarrier* b : *dependency->buffer_barriers()) {
            MemoryBarrier masks{b->src_stage_mask(), b->src_access_mask(), b->dst_stage_mask(), b->dst_access_mask()};
            if (auto range = memory_.buffer_range(b->buffer(), b->offset(), b->size())) {
                out.push_back({masks, *range});
            } else {
                // A buffer the trace never bound: keep the execution dependency only.
                global->push_back({masks.src_stages, 0, masks.dst_stages, 0});
            }
        }
    }
    return out;
}

void Replay::barrier(const fbs::Record& record, const CommandRef& ref) {
    ++report_.counts.barriers;
    if (!options_.check_hazards) return;
    std::vector<MemoryBarrier> global;
    switch (record.body_type()) {
    case fbs::RecordBody::CmdPipelineBarrier: {
        const fbs::CmdPipelineBarrier* b = record.body_as_CmdPipelineBarrier();
        std::vector<BufferBarrier> buffers = buffer_barriers(b->dependency(), &global);
        if (b->version() == 1 && global.empty() && buffers.empty())
            global.push_back(execution_barrier_v1(static_cast<VkPipelineStageFlags>(b->src_stage_mask()),
                                                  static_cast<VkPipelineStageFlags>(b->dst_stage_mask())));
        sync_.pipeline_barrier(ref, DependencyInfo{global, buffers, b->dependency() ? b->dependency()->dependency_flags() : 0});
        break;
    }
    case fbs::RecordBody::CmdSetEvent: {
        const fbs::CmdSetEvent* e = record.body_as_CmdSetEvent();
        if (e->version() == 1 || !e->dependency()) {
            sync_.set_event_v1(ref, e->event(), static_cast<VkPipelineStageFlags>(e->stage_mask()));
        } else {
            std::vector<BufferBarrier> buffers = buffer_barriers(e->dependency(), &global);
            sync_.set_event(ref, e->event(), DependencyInfo{global, buffers, e->dependency()->dependency_flags()});
        }
        break;
    }
    case fbs::RecordBody::CmdResetEvent: sync_.reset_event(ref, record.body_as_CmdResetEvent()->event()); break;
    case fbs::RecordBody::CmdWaitEvents: {
        const fbs::CmdWaitEvents* w = record.body_as_CmdWaitEvents();
        if (!w->events()) break;
        std::vector<uint64_t> events(w->events()->begin(), w->events()->end());
        const auto* deps = w->dependencies();
        if (w->version() == 1 || !deps || deps->size() != events.size()) {
            std::vector<BufferBarrier> buffers =
                buffer_barriers(deps && deps->size() ? deps->Get(0) : nullptr, &global);
            if (global.empty() && buffers.empty())
                global.push_back(execution_barrier_v1(static_cast<VkPipelineStageFlags>(w->src_stage_mask()),
                                                      static_cast<VkPipelineStageFlags>(w->dst_stage_mask())));
            sync_.wait_events(ref, events, DependencyInfo{global, buffers, 0});
        } else {
            // vkCmdWaitEvents2: one VkDependencyInfo per event.
            for (size_t i = 0; i < events.size(); ++i) {
                global.clear();
                std::vector<BufferBarrier> buffers = buffer_barriers(deps->Get(static_cast<flatbuffers::uoffset_t>(i)), &global);
                sync_.wait_events(ref, std::span<const uint64_t>(&events[i], 1), DependencyInfo{global, buffers, 0});
            }
        }
        break;
    }
    default: break;
    }
}

void Replay::copy_buffer(const fbs::CmdCopyBuffer& copy, const CommandRef& ref, const ReplayLocation& where) {
    ++report_.counts.copies;
    lay_in_snapshots(copy.inputs(), where);
    if (!copy.regions()) return;
    std::vector<uint8_t> bytes;
    uint32_t i = 0;
    for (const fbs::BufferCopy* region : *copy.regions()) {
        auto src = memory_.buffer_range(copy.src_buffer(), region->src_offset(), region->size());
        auto dst = memory_.buffer_range(copy.dst_buffer(), region->dst_offset(), region->size());
        if (src && dst) {
            if (memory_.read(src->begin, src->end - src->begin, &bytes)) memory_.write(dst->begin, bytes);
            if (options_.check_hazards) {
                report_.counts.accesses += 2;
                std::string src_field = "pRegions[" + std::to_string(i) + "].srcOffset";
                std::string dst_field = "pRegions[" + std::to_string(i) + "].dstOffset";
                sync_.record_copy(ref, Access{*src, VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_READ_BIT, false, src_field},
                                  Access{*dst, VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, true, dst_field});
            }
        }
        ++i;
    }
}

void Replay::fill_buffer(const fbs::CmdFillBuffer& fill, const CommandRef& ref) {
    ++report_.counts.copies;
    auto range = memory_.buffer_range(fill.dst_buffer(), fill.dst_offset(), fill.size());
    if (!range) return;
    if (fill.size() == kWholeSize) range->end = range->begin + ((range->end - range->begin) & ~3ull);
    memory_.fill(range->begin, range->end - range->begin, fill.data());
    feed(ref, *range, VK_PIPELINE_STAGE_2_CLEAR_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, true, "dstOffset");
}

void Replay::update_buffer(const fbs::CmdUpdateBuffer& update, const CommandRef& ref) {
    ++report_.counts.copies;
    const uint64_t size = update.data() ? update.data()->size() : 0;
    auto range = memory_.buffer_range(update.dst_buffer(), update.dst_offset(), size);
    if (!range || size == 0) return;
    memory_.write(range->begin, std::span<const uint8_t>(update.data()->data(), range->end - range->begin));
    feed(ref, *range, VK_PIPELINE_STAGE_2_CLEAR_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT, true, "pData");
}

void Replay::dispatch(const fbs::CmdDispatch& d, const CommandRef& ref, const ReplayLocation& where) {
    lay_in_snapshots(d.inputs(), where);
    if (d.indirect_buffer() != 0) {
        if (auto r = memory_.buffer_range(d.indirect_buffer(), d.indirect_offset(), 12))
            feed(ref, *r, VK_PIPELINE_STAGE_2_DRAW_INDIRECT_BIT, VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT, false, "indirect buffer");
    }
    if (d.storage_buffers()) {
        // Which bytes a shader writes is unknown: every bound storage range counts as read and written.
        for (const fbs::BoundBufferRange* b : *d.storage_buffers()) {
            std::optional<AddressRange> r;
            if (b->address() != 0 && b->range() != kWholeSize) {
                r = AddressRange{b->address(), b->address() + b->range()};
            } else {
                r = memory_.buffer_range(b->buffer(), b->offset(), b->range());
            }
            if (!r) continue;
            std::string field = "set " + std::to_string(b->set()) + " binding " + std::to_string(b->binding()) + "[" +
                                std::to_string(b->array_element()) + "]";
            feed(ref, *r, VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT,
                 VK_ACCESS_2_SHADER_STORAGE_READ_BIT | VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT, true, field);
        }
    }
    // The shader's effect is whatever the capture saw it write.
    if (d.outputs()) {
        std::vector<uint8_t> bytes;
        for (const fbs::MemorySnapshot* s : *d.outputs()) {
            auto address = memory_.snapshot_address(s->buffer(), s->offset(), s->address());
            if (address && contents(s->hash(), &bytes)) memory_.write(*address, bytes);
        }
    }
}

void Replay::build_nv(const fbs::CmdBuildAccelerationStructureNV& b, const CommandRef& ref, const ReplayLocation& where) {
    nv_.build(b, ref, where);  // nv_command.cpp
}

void Replay::copy_to_object(const fbs::CmdCopyMemoryToAccelerationStructure& c, const CommandRef& ref,
                            const ReplayLocation& where) {
    nv_.deserialize(c, ref, where);  // nv_command.cpp
}

void Replay::execute_command(const fbs::Record& record, const CommandRef& ref, uint64_t sequence) {
    const ReplayLocation where = location(ref, sequence);
    ++report_.counts.commands;
    switch (record.body_type()) {
    case fbs::RecordBody::CmdPipelineBarrier:
    case fbs::RecordBody::CmdSetEvent:
    case fbs::RecordBody::CmdResetEvent:
    case fbs::RecordBody::CmdWaitEvents: barrier(record, ref); break;
    case fbs::RecordBody::CmdCopyBuffer: copy_buffer(*record.body_as_CmdCopyBuffer(), ref, where); break;
    case fbs::RecordBody::CmdFillBuffer: fill_buffer(*record.body_as_CmdFillBuffer(), ref); break;
    case fbs::RecordBody::CmdUpdateBuffer: update_buffer(*record.body_as_CmdUpdateBuffer(), ref); break;
    case fbs::RecordBody::CmdDispatch: dispatch(*record.body_as_CmdDispatch(), ref, where); break;
    case fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect: {
        const auto& build = *record.body_as_CmdBuildClusterAccelerationStructureIndirect();
        lay_in_snapshots(build.inputs(), where);
        uint32_t queried = 0;
        if (build.input()) {
            auto it = queried_max_count_.find({build.input()->op_type(), build.input()->op_mode()});
            if (it != queried_max_count_.end()) queried = it->second;
        }
        detail::ClusterCommandContext context{memory_, directory_, translation_, properties_, options_, report_, sync_,
                                              ref,     where,      report_.engine_trace,
                                              [this](ReplayFinding f) { add_finding(std::move(f)); },
                                              [this](uint64_t hash, std::vector<uint8_t>* out) { return contents(hash, out); },
                                              observed_execution_, observed_engine_ns_};
        detail::run_cluster_command(build, queried, context);
        break;
    }
    case fbs::RecordBody::CmdBuildAccelerationStructureNV:
        build_nv(*record.body_as_CmdBuildAccelerationStructureNV(), ref, where);
        break;
    case fbs::RecordBody::CmdCopyMemoryToAccelerationStructure:
        copy_to_object(*record.body_as_CmdCopyMemoryToAccelerationStructure(), ref, where);
        break;
    default: --report_.counts.commands; break;  // timestamps, labels: nothing to replay
    }
}

void Replay::reset_command_buffers(const fbs::CommandBufferReset& reset) {
    if (reset.command_buffer() != 0) {
        forget_recorded(reset.command_buffer());
        if (reset.command_pool() != 0) pool_members_[reset.command_pool()].insert(reset.command_buffer());
        return;
    }
    if (reset.command_pool() == 0) return;
    auto members = pool_members_.find(reset.command_pool());
    if (members == pool_members_.end()) {
        if (!pools_noted_.insert(reset.command_pool()).second) return;  // a pool reset every frame: noted once
        ReplayLocation where;
        where.submission = next_submission_;
        where.name = "vkResetCommandPool";
        report_.not_replayed.push_back({where, "vkResetCommandPool(" + detail::hex(reset.command_pool()) +
                                                   "): the trace does not say which command buffers the pool holds; "
                                                   "a buffer submitted again without being re-recorded replays its old commands"});
        return;
    }
    for (uint64_t cb : members->second) forget_recorded(cb);
}

void Replay::check_binary_signals(const fbs::QueueSubmit& submit, uint32_t batch, std::span<const SemaphoreWait> waits,
                                  std::span<const SemaphoreSignal> signals) {
    // A wait value of 0 is a binary semaphore (timeline values start above 0), as in SyncModel.
    for (const SemaphoreWait& w : waits)
        if (w.value == 0) binary_signals_.consume(w.semaphore);
    const bool v2 = submit.version() >= 2;
    const uint32_t submission = static_cast<uint32_t>(submit.submission_index());
    for (size_t i = 0; i < signals.size(); ++i) {
        if (signals[i].value != 0) continue;
        const std::string here = "submission " + std::to_string(submission) + " batch " + std::to_string(batch);
        const std::string earlier = binary_signals_.signal(signals[i].semaphore, here);
        if (earlier.empty()) continue;
        ReplayLocation where;
        where.sequence = sequence_;
        where.submission = submission;
        where.name = v2 ? "vkQueueSubmit2" : "vkQueueSubmit";
        const std::string field = v2 ? "pSubmits[" + std::to_string(batch) + "].pSignalSemaphoreInfos[" + std::to_string(i) + "]"
                                     : "pSubmits[" + std::to_string(batch) + "].pSignalSemaphores[" + std::to_string(i) + "]";
        add_finding({v2 ? "VUID-vkQueueSubmit2-semaphore-03868" : "VUID-vkQueueSubmit-pSignalSemaphores-00067",
                     field + ": binary semaphore " + detail::hex(signals[i].semaphore) + " is signalled by " + here +
                         " while still signalled by " + earlier +
                         " (no submission or present waited on it in between)",
                     FindingSource::kReplay, where, -1, 0});
    }
}

void Replay::on_submit(const fbs::QueueSubmit& submit) {
    const uint32_t submission = static_cast<uint32_t>(submit.submission_index());
    if (submission != next_submission_) binary_signals_.forget_all();  // submissions left out of the trace
    next_submission_ = submission + 1;
    host_ops_ = 0;
    ++report_.counts.submissions;
    if (submit.result() != VK_SUCCESS) return;  // nothing reached the queue
    if (options_.observer) options_.observer->on_submission_begin(submission);
    const QueueId queue = queue_id(submit.queue());
    const auto* batches = submit.batches();
    const size_t batch_count = batches ? batches->size() : 0;
    uint32_t cb_index = 0;
    for (size_t b = 0; b < std::max<size_t>(batch_count, 1); ++b) {
        const fbs::SubmitBatch* batch = batch_count ? batches->Get(static_cast<flatbuffers::uoffset_t>(b)) : nullptr;
        std::vector<SemaphoreWait> waits;
        std::vector<SemaphoreSignal> signals;
        if (batch && batch->wait_semaphores())
            for (const fbs::SemaphoreOp* w : *batch->wait_semaphores())
                waits.push_back({w->semaphore(), w->value(),
                                 w->stage_mask() ? w->stage_mask() : StageMask(VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT)});
        if (batch && batch->signal_semaphores())
            for (const fbs::SemaphoreOp* s : *batch->signal_semaphores())
                // vkQueueSubmit signals are ALL_COMMANDS by the spec (their stage_mask is 0 or that).
                signals.push_back({s->semaphore(), s->value(),
                                   submit.version() >= 2 && s->stage_mask() ? StageMask(s->stage_mask())
                                                                            : StageMask(VK_PIPELINE_STAGE_2_ALL_COMMANDS_BIT)});
        check_binary_signals(submit, static_cast<uint32_t>(b), waits, signals);
        if (options_.check_hazards) sync_.begin_submission(queue, submission, waits);
        if (batch && batch->command_buffers()) {
            for (uint64_t handle : *batch->command_buffers()) {
                run_command_buffer(handle, submission, cb_index, nullptr);
                ++cb_index;
            }
        }
        if (options_.check_hazards) sync_.end_submission(signals, b + 1 >= batch_count ? submit.fence() : 0);
        memory_.note_peak();
    }
    // Restated copies serve this submission only; the recording itself may be submitted again.
    for (const auto& [handle, count] : executions_)
        if (auto it = recorded_.find(handle); it != recorded_.end() && !it->second.restated.empty()) {
            uint64_t copies = 0;
            for (const Commands& copy : it->second.restated)
                for (const auto& bytes : copy) copies += bytes.size();
            copies = std::min(copies, it->second.bytes);
            it->second.bytes -= copies;
            recorded_bytes_ -= std::min(recorded_bytes_, copies);
            it->second.restated.clear();
            it->second.filling = 0;
        }
    executions_.clear();
    limit_recorded();
    if (options_.observer) options_.observer->on_submission_end(submission);
}

void Replay::run_command_buffer(uint64_t handle, uint32_t submission, uint32_t cb_index, const CommandRef* inside) {
    const char* where_name = inside ? "vkCmdExecuteCommands" : "vkQueueSubmit";
    auto location_here = [&] {
        ReplayLocation where{sequence_, submission, cb_index, 0, handle, where_name};
        if (inside) {
            where.command_buffer_handle = inside->command_buffer_handle;
            where.command = inside->command;
            where.secondary_handle = handle;
            where.secondary = inside->secondary;
        }
        return where;
    };
    auto it = recorded_.find(handle);
    if (it == recorded_.end()) {
        if (dropped_.count(handle))
            add_finding({"CLASTRACE-replay-command-buffer-dropped",
                         "command buffer " + detail::hex(handle) +
                             " is submitted again, but its commands were dropped to keep the replay within "
                             "ReplayOptions::max_recorded_bytes (" + std::to_string(options_.max_recorded_bytes) +
                             "): not replayed",
                         FindingSource::kReplay, location_here(), -1, 0});
        else  // Reset (buffer or pool), never begun in the trace, or a one-time buffer submitted again.
            add_finding({"CLASTRACE-replay-command-buffer-not-recorded",
                         "command buffer " + detail::hex(handle) +
                             " holds no recorded commands (reset, never begun in the trace, or "
                             "ONE_TIME_SUBMIT and already submitted): nothing of it is replayed",
                         FindingSource::kReplay, location_here(), -1, 0});
        return;
    }
    Recorded& recorded = it->second;
    recorded.submitted = uint64_t(submission) + 1;
    const uint32_t execution = executions_[handle]++;
    const Commands& commands = recorded.copy_for(execution);
    uint32_t command = 0;
    for (const std::vector<uint8_t>& bytes : commands) {
        const fbs::Record* record = flatbuffers::GetRoot<fbs::Record>(bytes.data());
        const uint64_t sequence = sequence_++;
        CommandRef ref{submission, cb_index, handle, command, command_name(record->body_type())};
        if (inside) {
            ref = *inside;
            ref.name = command_name(record->body_type());
            ref.secondary_handle = handle;
            ref.secondary_command = command;
        }
        replay_command(*record, ref, sequence, selected(sequence, submission));
        // The secondaries' commands get their own sequence numbers and are selected (--ops) one
        // by one, whether or not the execute command itself is.
        if (record->body_type() == fbs::RecordBody::CmdExecuteCommands) {
            if (inside) {
                if (selected(sequence, submission))
                    report_.not_replayed.push_back({location(ref, sequence),
                                                    "vkCmdExecuteCommands inside a secondary command buffer "
                                                    "(VK_EXT_nested_command_buffer): the nested secondaries are not "
                                                    "replayed"});
            } else {
                execute_secondaries(*record->body_as_CmdExecuteCommands(), ref);
            }
        }
        ++command;
    }
    if (!inside && recorded.one_time) forget_recorded(handle);
}

// The secondaries run inline, in list order, as part of the primary's command-buffer order:
// the synchronization model sees their commands between the primary's commands before and
// after the vkCmdExecuteCommands.
void Replay::execute_secondaries(const fbs::CmdExecuteCommands& execute, const CommandRef& ref) {
    if (!execute.secondaries()) return;
    uint32_t index = 0;
    for (uint64_t secondary : *execute.secondaries()) {
        CommandRef inside = ref;
        inside.secondary = index++;
        auto it = recorded_.find(secondary);
        if (it != recorded_.end() && !it->second.secondary)
            add_finding({"VUID-vkCmdExecuteCommands-pCommandBuffers-00088",
                         "pCommandBuffers[" + std::to_string(inside.secondary) + "] (" + detail::hex(secondary) +
                             ") was begun as a primary command buffer (CommandBufferBegin level 0): it is replayed "
                             "inline all the same",
                         FindingSource::kReplay, location(ref, sequence_), -1, 0});
        run_command_buffer(secondary, ref.submission, ref.command_buffer, &inside);
    }
}

// Each record outside a command buffer goes to the handler of its family; the others are
// commands, kept in their command buffer until it is submitted.
void Replay::on_record(const traces::RecordView& view) {
    const fbs::Record& r = *view.record;
    const fbs::RecordBody kind = view.kind;
    if (on_memory_record(kind, r) || on_acceleration_structure_record(kind, r) || on_command_buffer_record(kind, r) ||
        on_queue_record(kind, r) || on_presentation_record(kind, r) || on_check_record(kind, r))
        return;
    record_command(view);
}

// Buffers and device memory: the replay's address space, and the host's writes to mapped memory.
bool Replay::on_memory_record(fbs::RecordBody kind, const fbs::Record& r) {
    switch (kind) {
    case fbs::RecordBody::BufferCreate: {
        const auto* c = r.body_as_BufferCreate();
        memory_.create_buffer(c->buffer(), c->size(), c->usage());
        break;
    }
    case fbs::RecordBody::BufferBindMemory: {
        const auto* b = r.body_as_BufferBindMemory();
        memory_.bind_buffer(b->buffer(), b->memory(), b->memory_offset(), b->device_address());
        break;
    }
    case fbs::RecordBody::BufferDestroy: memory_freed(memory_.destroy_buffer(r.body_as_BufferDestroy()->buffer())); break;
    case fbs::RecordBody::MemoryFree: memory_.free_memory(r.body_as_MemoryFree()->memory()); break;
    case fbs::RecordBody::MemoryObservation: host_observation(*r.body_as_MemoryObservation()); break;
    default: return false;
    }
    return true;
}

// Acceleration-structure objects (create, bind, destroy) and the size queries a build
// is checked against.
bool Replay::on_acceleration_structure_record(fbs::RecordBody kind, const fbs::Record& r) {
    switch (kind) {
    case fbs::RecordBody::AccelerationStructureCreate: {
        const auto* c = r.body_as_AccelerationStructureCreate();
        memory_.create_object(c->acceleration_structure(), c->buffer(), c->offset(), c->size(), 0);
        nv_.on_create(*c);
        break;
    }
    case fbs::RecordBody::AccelerationStructureMemoryRequirementsNV: {
        const auto* q = r.body_as_AccelerationStructureMemoryRequirementsNV();
        if (q->type() == VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_OBJECT_NV)
            memory_.object_requirement(q->acceleration_structure(), q->size());
        nv_.on_requirement(*q);
        break;
    }
    case fbs::RecordBody::AccelerationStructureBindMemory: {
        const auto* b = r.body_as_AccelerationStructureBindMemory();
        memory_.bind_object(b->acceleration_structure(), b->memory(), b->memory_offset());
        nv_.on_bind(*b);
        break;
    }
    case fbs::RecordBody::AccelerationStructureDestroy:
        memory_.destroy_object(r.body_as_AccelerationStructureDestroy()->acceleration_structure());
        break;
    case fbs::RecordBody::GetClusterBuildSizes: {
        const auto* q = r.body_as_GetClusterBuildSizes();
        if (q->input()) {
            uint32_t& m = queried_max_count_[{q->input()->op_type(), q->input()->op_mode()}];
            m = std::max(m, q->input()->max_acceleration_structure_count());
        }
        break;
    }
    default: return false;
    }
    return true;
}

// Command buffers' lifetimes: a begin starts a recording (or a restatement of one), a reset
// forgets it.
bool Replay::on_command_buffer_record(fbs::RecordBody kind, const fbs::Record& r) {
    switch (kind) {
    case fbs::RecordBody::CommandBufferBegin: {
        const fbs::CommandBufferBegin* begin = r.body_as_CommandBufferBegin();
        Recorded& cb = recorded_[begin->command_buffer()];
        if (const uint32_t k = begin->restatement(); k != 0) {
            // Copy k of the recording, for the (k+1)-th execution in the next submission; a
            // hostile index cannot make the list longer than the copies actually written.
            if (k > cb.restated.size() + 1) {
                add_finding({"CLASTRACE-replay-restatement-out-of-order",
                             "CommandBufferBegin of " + detail::hex(begin->command_buffer()) + " restates execution " +
                                 std::to_string(k) + " but only " + std::to_string(cb.restated.size()) +
                                 " restatement(s) precede it: its commands are kept as restatement " +
                                 std::to_string(cb.restated.size() + 1),
                             FindingSource::kReplay, ReplayLocation{sequence_, next_submission_, 0, 0,
                                                                    begin->command_buffer(), "vkBeginCommandBuffer"},
                             -1, 0});
            }
            const size_t slot = std::min<size_t>(k, cb.restated.size() + 1);
            if (slot > cb.restated.size()) cb.restated.emplace_back();
            cb.restated[slot - 1].clear();
            cb.filling = static_cast<uint32_t>(slot);
            break;
        }
        drop_recorded(cb);
        cb = Recorded{};
        dropped_.erase(begin->command_buffer());
        cb.one_time = begin->flags() & VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
        cb.secondary = begin->level() == 1;
        break;
    }
    case fbs::RecordBody::CommandBufferReset: reset_command_buffers(*r.body_as_CommandBufferReset()); break;
    default: return false;
    }
    return true;
}

// Queue work and what the host waits for: submissions run their command buffers; waits tell
// the synchronization model what completed.
bool Replay::on_queue_record(fbs::RecordBody kind, const fbs::Record& r) {
    switch (kind) {
    case fbs::RecordBody::QueueSubmit: on_submit(*r.body_as_QueueSubmit()); break;
    case fbs::RecordBody::QueueWaitIdle:
        if (options_.check_hazards) sync_.queue_wait_idle(queue_id(r.body_as_QueueWaitIdle()->queue()));
        break;
    case fbs::RecordBody::DeviceWaitIdle:
        if (options_.check_hazards) sync_.device_wait_idle();
        break;
    case fbs::RecordBody::FenceWait: {
        const auto* w = r.body_as_FenceWait();
        if (options_.check_hazards && w->result() == VK_SUCCESS && w->fences() && (w->wait_all() || w->fences()->size() == 1))
            for (uint64_t f : *w->fences()) sync_.wait_for_fence(f);
        break;
    }
    case fbs::RecordBody::FenceStatus: {
        const auto* s = r.body_as_FenceStatus();
        if (options_.check_hazards && s->result() == VK_SUCCESS) sync_.wait_for_fence(s->fence());
        break;
    }
    case fbs::RecordBody::HostSemaphoreOp: {
        const auto* h = r.body_as_HostSemaphoreOp();
        if (!options_.check_hazards || !h->semaphores() || !h->values() || h->result() != VK_SUCCESS) break;
        const size_t n = std::min(h->semaphores()->size(), h->values()->size());
        for (size_t i = 0; i < n; ++i) {
            auto k = static_cast<flatbuffers::uoffset_t>(i);
            if (h->op() == 0) sync_.host_signal_semaphore(h->semaphores()->Get(k), h->values()->Get(k));
            else if (!h->wait_any() || n == 1) sync_.host_wait_semaphore(h->semaphores()->Get(k), h->values()->Get(k));
        }
        break;
    }
    default: return false;
    }
    return true;
}

// Swapchain images: acquires signal, presents wait.
bool Replay::on_presentation_record(fbs::RecordBody kind, const fbs::Record& r) {
    switch (kind) {
    case fbs::RecordBody::AcquireNextImage: {
        const auto* a = r.body_as_AcquireNextImage();
        ++report_.counts.acquires;
        // VK_SUCCESS / VK_SUBOPTIMAL_KHR: the presentation engine signals the semaphore and fence.
        // vkAcquireNextImage2KHR's deviceMask is never 0 (VUID-VkAcquireNextImageInfoKHR-deviceMask-01290).
        const bool v2 = a->device_mask() != 0;
        const char* name = v2 ? "vkAcquireNextImage2KHR" : "vkAcquireNextImageKHR";
        const bool signals = a->result() == VK_SUCCESS || a->result() == VK_SUBOPTIMAL_KHR;
        if (a->semaphore()) {
            // Whatever the result, the semaphore had to be unsignalled at the call.
            const std::string here = std::string(name) + " (swapchain " + detail::hex(a->swapchain()) + ", image " +
                                     std::to_string(a->image_index()) + ")";
            const std::string earlier =
                signals ? binary_signals_.signal(a->semaphore(), here) : binary_signals_.signalled_by(a->semaphore());
            if (!earlier.empty()) {
                ReplayLocation where;
                where.sequence = sequence_;
                where.submission = next_submission_;
                where.name = name;
                add_finding({v2 ? "VUID-VkAcquireNextImageInfoKHR-semaphore-01288" : "VUID-vkAcquireNextImageKHR-semaphore-01286",
                             std::string(v2 ? "pAcquireInfo->semaphore" : "semaphore") + ": binary semaphore " +
                                 detail::hex(a->semaphore()) + " is still signalled by " + earlier +
                                 " (no submission or present waited on it in between)",
                             FindingSource::kReplay, where, -1, 0});
            }
        }
        if (!signals) break;
        if (options_.check_hazards) sync_.acquire_signal(a->semaphore(), a->fence());
        break;
    }
    case fbs::RecordBody::QueuePresent: {
        const auto* p = r.body_as_QueuePresent();
        ++report_.counts.presents;
        if (p->wait_semaphores())
            for (uint64_t semaphore : *p->wait_semaphores()) binary_signals_.consume(semaphore);
        if (options_.check_hazards && p->wait_semaphores())
            sync_.present_wait(std::span<const uint64_t>(p->wait_semaphores()->data(), p->wait_semaphores()->size()));
        break;
    }
    default: return false;
    }
    return true;
}

// Checks the capture made on the device, compared with the replay's own result.
bool Replay::on_check_record(fbs::RecordBody kind, const fbs::Record& r) {
    switch (kind) {
    case fbs::RecordBody::RayQueryCheck: nv_.ray_check(*r.body_as_RayQueryCheck()); break;
    default: return false;
    }
    return true;
}

// A command: appended to the recording (or restatement) its command buffer is filling.
void Replay::record_command(const traces::RecordView& view) {
    const fbs::Record& r = *view.record;
    if (uint64_t cb = command_buffer_of(r)) {
        Recorded& recorded = recorded_[cb];
        recorded.target().emplace_back(view.bytes, view.bytes + view.size);
        recorded.bytes += view.size;
        recorded_bytes_ += view.size;
    }
}

ReplayReport Replay::run() {
    traces::RecordView view;
    ReplayProgress progress;
    while (reader_.next(&view)) {
        ++report_.counts.records;
        if (options_.observer) options_.observer->on_record(view);
        on_record(view);
        if (options_.progress && (report_.counts.records & 63) == 0) {
            progress.bytes_read = view.chunk_offset;
            progress.file_size = reader_.stats().file_size;
            progress.records = report_.counts.records;
            progress.commands = report_.counts.commands;
            options_.progress(progress);
        }
    }
    for (const traces::TraceError& e : reader_.damage()) report_.trace_damage.push_back(e.message);
    for (const auto& [buffer, size] : memory_.over_budget())
        add_finding({"CLASTRACE-replay-memory-budget",
                     "buffer " + detail::hex(buffer) + " (" + std::to_string(size) +
                         " bytes) was left out of the replay's memory: the address space of all buffers would exceed " +
                         std::to_string(ReplayMemory::kReservedLimit) + " bytes",
                     FindingSource::kReplay, ReplayLocation{}, -1, 0});
    if (memory_.writes_over_budget())
        add_finding({"CLASTRACE-replay-memory-budget",
                     std::to_string(memory_.writes_over_budget()) +
                         " write(s) to memory were refused: the replay's memory would hold more than the budget of " +
                         std::to_string(options_.memory_budget_bytes) + " bytes (ReplayOptions::memory_budget_bytes)",
                     FindingSource::kReplay, ReplayLocation{}, -1, 0});
    memory_.note_peak();
    report_.counts.peak_image_bytes = memory_.peak_resident_bytes();
    if (options_.check_hazards) {
        report_.hazards = merge_per_op_hazards(sync_.hazards(), &report_.hazards_merged);
        report_.hazards_over_cap = sync_.stats().hazards_over_cap;
        report_.counts.unsatisfied_semaphore_waits = sync_.stats().unsatisfied_waits;
    }
    return std::move(report_);
}

}  // namespace

ReplayReport replay_trace(TraceReader& reader, const std::string& trace_name, const ReplayOptions& options) {
    Replay replay(reader, trace_name, options);
    return replay.run();
}

}  // namespace clastrace::replay
