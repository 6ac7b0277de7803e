// SPDX-License-Identifier: Apache-2.0
// replay_trace: streams the trace, queues each command buffer's commands until it is
// submitted, then executes them in submission order (see replayer.h).
// Each family of records has its handlers in its own file (replayer_internal.hpp lists them);
// this file keeps the public API, the stream and the dispatch.
#include "clastrace/replay/replayer.h"

#include "replayer_internal.h"

#include <chrono>

namespace clastrace::replay {

bool is_engine_device(const std::string& driver_name) {
    return driver_name.rfind("clastrace", 0) == 0;
}

namespace detail {

Replay::Replay(TraceReader& reader, const std::string& name, const ReplayOptions& options)
    : reader_(reader),
      options_(options),
      memory_(options.memory_budget_bytes),
      sync_(SyncOptions{options.max_findings}) {
    report_.trace = name;
    sync_.set_address_resolver(&memory_, [this](const CommandRef& ref, const Access& access,
                                                AddressRange unbound) {
        unbound_access(ref, access, unbound);
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

void Replay::execute_command(const fbs::Record& record, const CommandRef& ref, uint64_t sequence) {
    const ReplayLocation where = location(ref, sequence);
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
void Replay::replay_command(const fbs::Record& record, const CommandRef& ref, uint64_t sequence,
                            bool selected) {
    ReplayObserver* observer = options_.observer;
    const size_t findings = report_.findings.size(),
                 hazards = options_.check_hazards ? sync_.hazards().size() : 0;
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
        execute_command(record, ref, sequence);
    } else {
        ++report_.counts.skipped_commands;
    }
    if (!observer) return;
    observed_execution_ = nullptr;
    observed_engine_ns_ = nullptr;
    ReplayedCommand c{location(ref, sequence),
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
    return std::move(report_);
}

}  // namespace detail

ReplayReport replay_trace(traces::TraceReader& reader, const std::string& trace_name,
                          const ReplayOptions& options) {
    detail::Replay replay(reader, trace_name, options);
    return replay.run();
}

}  // namespace clastrace::replay
