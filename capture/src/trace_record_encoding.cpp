// SPDX-License-Identifier: Apache-2.0
// Record encoding of the capture layer (trace_record_encoding.h).
#include "trace_record_encoding.h"

#include <clastrace/traces/cluster_conversions.h>
#include <clastrace/traces/khr_conversions.h>
#include <clastrace/traces/nv_conversions.h>

#include <cstdio>
#include <string>

namespace clastrace::capture {
namespace {

std::unique_ptr<fbs::DependencyT> dependency(VkDependencyFlags flags,
                                             const std::vector<MemoryBarrier>& memory,
                                             const std::vector<BufferBarrier>& buffers,
                                             uint32_t images) {
    auto d = std::make_unique<fbs::DependencyT>();
    d->dependency_flags = flags;
    for (const auto& b : memory)
        d->memory_barriers.emplace_back(b.src_stage, b.src_access, b.dst_stage, b.dst_access);
    for (const auto& b : buffers)
        d->buffer_barriers.emplace_back(b.src_stage, b.src_access, b.dst_stage, b.dst_access,
                                        VK_QUEUE_FAMILY_IGNORED, VK_QUEUE_FAMILY_IGNORED, b.buffer,
                                        b.offset, b.size);
    d->image_barrier_count = images;
    return d;
}

fbs::RecordT encode(uint64_t cb, const BarrierCommand& c) {
    fbs::CmdPipelineBarrierT r;
    r.command_buffer = cb;
    r.version = c.synchronization2 ? 2 : 1;
    r.src_stage_mask = c.src_stage_mask;
    r.dst_stage_mask = c.dst_stage_mask;
    r.dependency =
        dependency(c.dependency_flags, c.memory_barriers, c.buffer_barriers, c.image_barrier_count);
    return record_of(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const EventCommand& c) {
    const uint8_t version = c.synchronization2 ? 2 : 1;
    if (c.kind == EventCommand::Kind::kSet) {
        fbs::CmdSetEventT r;
        r.command_buffer = cb;
        r.event = c.events.empty() ? 0 : c.events[0];
        r.version = version;
        r.stage_mask = c.src_stage_mask;
        if (c.synchronization2)
            r.dependency = dependency(0, c.memory_barriers, c.buffer_barriers, 0);
        return record_of(std::move(r));
    }
    if (c.kind == EventCommand::Kind::kReset) {
        fbs::CmdResetEventT r;
        r.command_buffer = cb;
        r.event = c.events.empty() ? 0 : c.events[0];
        r.version = version;
        r.stage_mask = c.src_stage_mask;
        return record_of(std::move(r));
    }
    fbs::CmdWaitEventsT r;
    r.command_buffer = cb;
    r.version = version;
    r.events = c.events;
    r.src_stage_mask = c.src_stage_mask;
    r.dst_stage_mask = c.dst_stage_mask;
    // The per-event split of v2 dependencies is not kept by the layer: one dependency.
    r.dependencies.push_back(dependency(0, c.memory_barriers, c.buffer_barriers, 0));
    return record_of(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const CopyBufferCommand& c) {
    fbs::CmdCopyBufferT r;
    r.command_buffer = cb;
    r.version = 1;
    r.src_buffer = c.src;
    r.dst_buffer = c.dst;
    for (const auto& region : c.regions)
        r.regions.emplace_back(region.srcOffset, region.dstOffset, region.size);
    return record_of(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const FillBufferCommand& c) {
    fbs::CmdFillBufferT r;
    r.command_buffer = cb;
    r.dst_buffer = c.dst;
    r.dst_offset = c.offset;
    r.size = c.size;
    r.data = c.data;
    return record_of(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const UpdateBufferCommand& c) {
    fbs::CmdUpdateBufferT r;
    r.command_buffer = cb;
    r.dst_buffer = c.dst;
    r.dst_offset = c.offset;
    r.data = c.data;
    return record_of(std::move(r));
}

std::vector<fbs::AccelerationStructureBinding> bindings_of(
    const std::vector<ReachableAccelerationStructure>& reachable) {
    std::vector<fbs::AccelerationStructureBinding> out;
    for (const auto& r : reachable)
        out.emplace_back(r.set, r.binding, r.array_element, uint32_t(r.source),
                         r.acceleration_structure, r.address);
    return out;
}

std::vector<fbs::BoundBufferRange> ranges_of(const std::vector<BoundStorageBuffer>& buffers) {
    std::vector<fbs::BoundBufferRange> out;
    for (const auto& b : buffers)
        out.emplace_back(b.set, b.binding, b.array_element, uint32_t(b.type), b.buffer, b.offset,
                         b.range, b.address);
    return out;
}

fbs::RecordT encode(uint64_t cb, const DispatchCommand& c) {
    fbs::CmdDispatchT r;
    r.command_buffer = cb;
    r.group_count_x = c.group_count_x;
    r.group_count_y = c.group_count_y;
    r.group_count_z = c.group_count_z;
    r.pipeline = c.pipeline;
    r.indirect_buffer = c.indirect_buffer;
    r.indirect_offset = c.indirect_offset;
    r.storage_buffers = ranges_of(c.storage_buffers);
    r.may_write_device_addresses = c.may_write_device_addresses;
    r.ray_query = c.ray_query;
    r.acceleration_structures = bindings_of(c.acceleration_structures);
    return record_of(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const DrawCommand& c) {
    fbs::CmdDrawT r;
    r.command_buffer = cb;
    r.pipeline = c.pipeline;
    r.entry_point = c.entry_point;
    r.address_stages = c.address_stages;
    r.ray_query_stages = c.ray_query_stages;
    r.acceleration_structures = bindings_of(c.acceleration_structures);
    return record_of(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const TraceRaysCommand& c) {
    fbs::CmdTraceRaysT r;
    r.command_buffer = cb;
    r.pipeline = c.pipeline;
    r.entry_point = c.entry_point;
    r.width = c.width;
    r.height = c.height;
    r.depth = c.depth;
    r.indirect_address = c.indirect_address;
    for (const VkStridedDeviceAddressRegionKHR& t : c.shader_binding_tables)
        r.shader_binding_tables.emplace_back(t.deviceAddress, t.stride, t.size);
    r.acceleration_structures = bindings_of(c.acceleration_structures);
    r.storage_buffers = ranges_of(c.storage_buffers);
    r.may_write_device_addresses = c.may_write_device_addresses;
    return record_of(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const ClusterBuildCommand& c) {
    return record_of(traces::cluster_commands_to_record(cb, c.parameters.resolved()));
}

fbs::RecordT encode(uint64_t cb, const BuildAccelerationStructureNVCommand& c) {
    fbs::CmdBuildAccelerationStructureNVT r;
    r.command_buffer = cb;
    r.info = nv_info_of(uint32_t(c.type), c.flags, c.instance_count, c.geometries);
    r.instance_data = c.instance_data;
    r.instance_offset = c.instance_offset;
    r.update = c.update == VK_TRUE;
    r.dst = c.dst;
    r.src = c.src;
    r.scratch = c.scratch;
    r.scratch_offset = c.scratch_offset;
    return record_of(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const CopyMemoryToAccelerationStructureCommand& c) {
    fbs::CmdCopyMemoryToAccelerationStructureT r;
    r.command_buffer = cb;
    r.src_address = c.src;
    r.dst = c.dst;
    r.mode = uint32_t(c.mode);
    return record_of(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const BuildAccelerationStructuresKHRCommand& c) {
    fbs::CmdBuildAccelerationStructuresKHRT r;
    r.command_buffer = cb;
    r.indirect = c.indirect;
    for (const KhrBuildInfo& info : c.infos) r.infos.push_back(khr_build_info_of(info));
    return record_of(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const CopyAccelerationStructureCommand& c) {
    if (c.to_memory) {
        fbs::CmdCopyAccelerationStructureToMemoryT r;
        r.command_buffer = cb;
        r.src = c.src;
        r.dst_address = c.dst_address;
        r.mode = uint32_t(c.mode);
        return record_of(std::move(r));
    }
    fbs::CmdCopyAccelerationStructureT r;
    r.command_buffer = cb;
    r.api = c.khr ? 1 : 0;
    r.src = c.src;
    r.dst = c.dst;
    r.mode = uint32_t(c.mode);
    return record_of(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const WriteAccelerationStructuresPropertiesCommand& c) {
    fbs::CmdWriteAccelerationStructuresPropertiesT r;
    r.command_buffer = cb;
    r.api = c.khr ? 1 : 0;
    r.acceleration_structures = c.acceleration_structures;
    r.query_type = uint32_t(c.query_type);
    r.query_pool = c.query_pool;
    r.first_query = c.first_query;
    return record_of(std::move(r));
}

// Written by the sink itself: the ticks and the secondaries' blocks depend on the submission.
fbs::RecordT encode(uint64_t, const TimestampWriteCommand&) { return {}; }
fbs::RecordT encode(uint64_t, const ExecuteCommandsCommand&) { return {}; }

}  // namespace

fbs::TraceHeaderT trace_header_of(const DeviceRecord& d, uint64_t start_time_unix_ns) {
    fbs::TraceHeaderT header;
    header.device = std::make_unique<fbs::DeviceInfoT>();
    fbs::DeviceInfoT& info = *header.device;
    info.name = d.device_name;
    info.vendor_id = d.vendor_id;
    info.device_id = d.device_id;
    info.driver_version = d.driver_version;
    info.api_version = d.api_version;
    info.device_type = d.device_type;
    info.pipeline_cache_uuid = d.pipeline_cache_uuid;
    if (d.served_by_layer) {
        // The cluster builds' outputs in this trace were written by clastrace's engine, not by
        // the device's driver: replay compares them with the engine byte for byte.
        info.driver_name = "clastrace engine";
        info.driver_info =
            "VK_NV_cluster_acceleration_structure served by VK_LAYER_CLASTRACE_capture: cluster "
            "builds executed by clastrace's CPU engine on the host; the device's driver ran "
            "everything else";
    } else if (!d.driver_name.empty()) {
        info.driver_id = d.driver_id;
        info.driver_name = d.driver_name;
        info.driver_info = d.driver_info;
    }
    info.driver_uuid = d.driver_uuid;
    info.device_uuid = d.device_uuid;
    if (d.has_ray_tracing_properties_nv) {
        const auto& rt = d.ray_tracing_properties_nv;
        info.ray_tracing_properties_nv = std::make_unique<fbs::RayTracingPropertiesNVT>();
        auto& o = *info.ray_tracing_properties_nv;
        o.shader_group_handle_size = rt.shaderGroupHandleSize;
        o.max_recursion_depth = rt.maxRecursionDepth;
        o.max_shader_group_stride = rt.maxShaderGroupStride;
        o.shader_group_base_alignment = rt.shaderGroupBaseAlignment;
        o.max_geometry_count = rt.maxGeometryCount;
        o.max_instance_count = rt.maxInstanceCount;
        o.max_triangle_count = rt.maxTriangleCount;
        o.max_descriptor_set_acceleration_structures = rt.maxDescriptorSetAccelerationStructures;
    }
    info.timestamp_period_ns = d.timestamp_period;
    for (const auto& t : d.memory_types)
        info.memory_types.emplace_back(t.propertyFlags, t.heapIndex);
    for (const auto& h : d.memory_heaps) info.memory_heaps.emplace_back(h.size, h.flags);
    info.enabled_extensions = d.enabled_extensions;
    info.cluster_features = std::make_unique<fbs::ClusterFeaturesT>();
    info.cluster_features->cluster_acceleration_structure_supported =
        d.cluster_properties.maxTrianglesPerCluster != 0;
    info.cluster_features->cluster_acceleration_structure_enabled = d.cluster_feature_enabled;
    info.cluster_properties = std::make_unique<fbs::ClusterPropertiesT>();
    auto& p = *info.cluster_properties;
    p.max_vertices_per_cluster = d.cluster_properties.maxVerticesPerCluster;
    p.max_triangles_per_cluster = d.cluster_properties.maxTrianglesPerCluster;
    p.cluster_scratch_byte_alignment = d.cluster_properties.clusterScratchByteAlignment;
    p.cluster_byte_alignment = d.cluster_properties.clusterByteAlignment;
    p.cluster_template_byte_alignment = d.cluster_properties.clusterTemplateByteAlignment;
    p.cluster_bottom_level_byte_alignment = d.cluster_properties.clusterBottomLevelByteAlignment;
    p.cluster_template_bounds_byte_alignment =
        d.cluster_properties.clusterTemplateBoundsByteAlignment;
    p.max_cluster_geometry_index = d.cluster_properties.maxClusterGeometryIndex;
    header.capture = std::make_unique<fbs::CaptureSettingsT>();
    header.capture->application_name = d.application_name;
    header.capture->engine_name = d.engine_name;
    header.capture->capture_tool = d.served_by_layer
                                       ? "clastrace-capture 0.1.0 (serving the extension)"
                                       : "clastrace-capture 0.1.0";
    header.capture->start_time_unix_ns = start_time_unix_ns;
    header.capture->snapshot_policy = "inputs+outputs";
    return header;
}

fbs::RecordT host_sync_record_of(const HostSyncRecord& h) {
    using K = HostSyncRecord::Kind;
    auto first = [&] { return h.handles.empty() ? 0 : h.handles[0]; };
    switch (h.kind) {
    case K::kEventSet:
    case K::kEventReset:
    case K::kEventStatus: {
        fbs::HostEventOpT r;
        r.event = first();
        r.op = h.kind == K::kEventSet ? 0 : h.kind == K::kEventReset ? 1 : 2;
        r.result = h.result;
        return record_of(std::move(r));
    }
    case K::kFenceWait: {
        fbs::FenceWaitT r;
        r.fences = h.handles;
        r.wait_all = h.wait_all;
        r.timeout = h.timeout;
        r.result = h.result;
        return record_of(std::move(r));
    }
    case K::kFenceReset: {
        fbs::FenceResetT r;
        r.fences = h.handles;
        return record_of(std::move(r));
    }
    case K::kFenceStatus: {
        fbs::FenceStatusT r;
        r.fence = first();
        r.result = h.result;
        return record_of(std::move(r));
    }
    case K::kQueueWaitIdle: {
        fbs::QueueWaitIdleT r;
        r.queue = first();
        r.result = h.result;
        return record_of(std::move(r));
    }
    case K::kDeviceWaitIdle: {
        fbs::DeviceWaitIdleT r;
        r.result = h.result;
        return record_of(std::move(r));
    }
    case K::kSemaphoreSignal:
    case K::kSemaphoreWait: break;
    }
    fbs::HostSemaphoreOpT r;
    r.op = h.kind == K::kSemaphoreSignal ? 0 : 1;
    r.semaphores = h.handles;
    r.values = h.values;
    r.wait_any = !h.wait_all;
    r.timeout = h.timeout;
    r.result = h.result;
    return record_of(std::move(r));
}

std::unique_ptr<fbs::AccelerationStructureInfoNVT> nv_info_of(
    uint32_t type, uint32_t flags, uint32_t instances,
    const std::vector<VkGeometryNV>& geometries) {
    VkAccelerationStructureInfoNV info{};
    info.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_INFO_NV;
    info.type = VkAccelerationStructureTypeNV(type);
    info.flags = flags;
    info.instanceCount = instances;
    info.geometryCount = uint32_t(geometries.size());
    info.pGeometries = geometries.data();
    return traces::nv_info_to_record(info);
}

std::unique_ptr<fbs::AccelerationStructureBuildInfoKHRT> khr_build_info_of(
    const KhrBuildInfo& info) {
    const VkAccelerationStructureBuildGeometryInfoKHR resolved = info.resolved();
    auto r = traces::khr_build_info_to_record(resolved,
                                              info.ranges.empty() ? nullptr : info.ranges.data());
    r->indirect_address = info.indirect_address;
    r->indirect_stride = info.indirect_stride;
    r->max_primitive_counts = info.max_primitive_counts;
    r->unrecorded_next_stypes = info.next_stypes;
    return r;
}

void set_indirect_ranges(
    const std::vector<std::vector<VkAccelerationStructureBuildRangeInfoKHR>>& ranges,
    fbs::CmdBuildAccelerationStructuresKHRT& record) {
    for (size_t i = 0; i < ranges.size() && i < record.infos.size(); ++i) {
        record.infos[i]->ranges.clear();
        for (const auto& range : ranges[i])
            record.infos[i]->ranges.push_back(traces::khr_range_to_record(range));
    }
}

fbs::QueryPoolResultsT query_pool_results_of(const QueryPoolResultsRecord& q) {
    fbs::QueryPoolResultsT r;
    r.query_pool = q.query_pool;
    r.first_query = q.first_query;
    r.values = q.values;
    r.result = q.result;
    return r;
}

fbs::GetAccelerationStructureBuildSizesKHRT khr_build_sizes_of(const KhrBuildSizesQuery& q) {
    fbs::GetAccelerationStructureBuildSizesKHRT r;
    r.build_type = uint32_t(q.build_type);
    r.info = khr_build_info_of(q.info);
    r.max_primitive_counts = q.max_primitive_counts;
    r.acceleration_structure_size = q.answer.accelerationStructureSize;
    r.update_scratch_size = q.answer.updateScratchSize;
    r.build_scratch_size = q.answer.buildScratchSize;
    return r;
}

fbs::RecordT command_record_of(uint64_t command_buffer, const RecordedCommand& command) {
    return std::visit([&](const auto& c) { return encode(command_buffer, c); }, command);
}

fbs::QueueSubmitT queue_submit_of(const SubmissionRecord& s, uint64_t submission_index) {
    fbs::QueueSubmitT submit;
    submit.queue = s.queue;
    submit.queue_family_index = s.queue_family;
    submit.queue_index = s.queue_index;
    submit.version = s.synchronization2 ? 2 : 1;
    for (const auto& b : s.batches) {
        auto batch = std::make_unique<fbs::SubmitBatchT>();
        for (const auto& w : b.waits)
            batch->wait_semaphores.emplace_back(w.semaphore, w.value, w.stage_mask, 0);
        batch->command_buffers = b.command_buffers;
        for (const auto& g : b.signals)
            batch->signal_semaphores.emplace_back(g.semaphore, g.value, g.stage_mask, 0);
        submit.batches.push_back(std::move(batch));
    }
    submit.fence = s.fence;
    submit.submission_index = submission_index;
    submit.result = VK_SUCCESS;
    return submit;
}

fbs::PreRangeStateT pre_range_state_of(const PreRangeStateRecord& m, uint64_t prelude_submission) {
    fbs::PreRangeStateT r;
    r.queue = m.queue;
    r.before_frame = m.first_frame;
    r.prelude_submission = prelude_submission;
    r.structures = m.structures;
    r.commands = m.commands;
    r.input_bytes = m.bytes;
    r.cluster_commands = m.cluster_commands;
    return r;
}

fbs::RayQueryCheckT ray_query_check_of(const RayCheckRecord& c, uint64_t after_submission) {
    fbs::RayQueryCheckT r;
    r.acceleration_structure = c.acceleration_structure;
    r.device_handle = c.device_handle;
    r.after_submission = after_submission;
    for (const NvTracedRay& ray : c.rays)
        r.rays.emplace_back(ray.origin[0], ray.origin[1], ray.origin[2], ray.t_min,
                            ray.direction[0], ray.direction[1], ray.direction[2], ray.t_max,
                            ray.ray_flags, ray.cull_mask);
    // NV GLSL has no gl_GeometryIndexEXT: the index comes from the hit record (stride 1), so it
    // is the driver's answer too.
    for (const NvRayHit& h : c.hits)
        r.results.emplace_back(h.hit, h.t, h.instance_custom_index, h.instance_id, h.primitive_id,
                               h.hit ? h.geometry_index : 0xFFFFFFFFu, h.hit_kind, h.u, h.v);
    r.label = c.label;
    return r;
}

void collect_findings(uint64_t command_buffer, size_t index, const ClusterBuildCapture& captured,
                      std::vector<fbs::CaptureFindingT>& out) {
    auto finding = [&](uint8_t severity, const std::string& rule, const std::string& message,
                       int64_t op) {
        fbs::CaptureFindingT r;
        r.command_buffer = command_buffer;
        r.command_index = uint32_t(index);
        r.op_index = op < 0 || op > int64_t(UINT32_MAX) ? UINT32_MAX : uint32_t(op);
        r.severity = severity;
        r.rule = rule;
        r.message = message;
        out.push_back(std::move(r));
    };
    for (const EngineFindingRecord& f : captured.engine_findings)
        finding(2, f.rule, f.message, f.op_index);
    for (const CaptureIssue& i : captured.issues) {
        char where[64];
        std::snprintf(where, sizeof where, " (address 0x%llx, %llu bytes)",
                      (unsigned long long)i.address, (unsigned long long)i.size);
        finding(1, "CLASTRACE-capture-incomplete", i.rule + where, -1);
    }
}

fbs::CaptureFindingT uncaptured_command_finding(uint64_t command_buffer, size_t index) {
    fbs::CaptureFindingT f;
    f.command_buffer = command_buffer;
    f.command_index = uint32_t(index);
    f.op_index = UINT32_MAX;
    f.severity = 1;
    f.rule = "CLASTRACE-capture-incomplete";
    f.message =
        "the queue never reached this command's pause before the process or the capture ended: "
        "its memory was not captured";
    return f;
}

fbs::CaptureFindingT submission_note_finding(const SubmissionRecord::Note& note) {
    fbs::CaptureFindingT f;
    f.command_buffer = note.command_buffer;
    f.command_index = UINT32_MAX;  // the whole command buffer
    f.op_index = UINT32_MAX;
    f.severity = 1;
    f.rule = note.rule;
    f.message = note.message;
    return f;
}

}  // namespace clastrace::capture
