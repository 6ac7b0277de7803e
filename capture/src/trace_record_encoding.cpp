// Record encoding of the capture layer (trace_record_encoding.h).
#include "trace_record_encoding.h"

#include <clastrace/traces/cluster_conversions.h>
#include <clastrace/traces/nv_conversions.h>

#include <cstdio>
#include <string>

namespace clastrace::capture {
namespace {

std::unique_ptr<fbs::DependencyT> dependency(VkDependencyFlags flags, const std::vector<MemoryBarrier>& memory,
                                             const std::vector<BufferBarrier>& buffers, uint32_t images) {
  auto d = std::make_unique<fbs::DependencyT>();
  d->dependency_flags = flags;
  for (const auto& b : memory) d->memory_barriers.emplace_back(b.srcStage, b.srcAccess, b.dstStage, b.dstAccess);
  for (const auto& b : buffers)
    d->buffer_barriers.emplace_back(b.srcStage, b.srcAccess, b.dstStage, b.dstAccess, VK_QUEUE_FAMILY_IGNORED,
                                    VK_QUEUE_FAMILY_IGNORED, b.buffer, b.offset, b.size);
  d->image_barrier_count = images;
  return d;
}

fbs::RecordT encode(uint64_t cb, const BarrierCommand& c) {
  fbs::CmdPipelineBarrierT r;
  r.command_buffer = cb;
  r.version = c.synchronization2 ? 2 : 1;
  r.src_stage_mask = c.srcStageMask;
  r.dst_stage_mask = c.dstStageMask;
  r.dependency = dependency(c.dependencyFlags, c.memoryBarriers, c.bufferBarriers, c.imageBarrierCount);
  return recordOf(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const EventCommand& c) {
  const uint8_t version = c.synchronization2 ? 2 : 1;
  if (c.kind == EventCommand::Kind::Set) {
    fbs::CmdSetEventT r;
    r.command_buffer = cb;
    r.event = c.events.empty() ? 0 : c.events[0];
    r.version = version;
    r.stage_mask = c.srcStageMask;
    if (c.synchronization2) r.dependency = dependency(0, c.memoryBarriers, c.bufferBarriers, 0);
    return recordOf(std::move(r));
  }
  if (c.kind == EventCommand::Kind::Reset) {
    fbs::CmdResetEventT r;
    r.command_buffer = cb;
    r.event = c.events.empty() ? 0 : c.events[0];
    r.version = version;
    r.stage_mask = c.srcStageMask;
    return recordOf(std::move(r));
  }
  fbs::CmdWaitEventsT r;
  r.command_buffer = cb;
  r.version = version;
  r.events = c.events;
  r.src_stage_mask = c.srcStageMask;
  r.dst_stage_mask = c.dstStageMask;
  // The per-event split of v2 dependencies is not kept by the layer: one dependency.
  r.dependencies.push_back(dependency(0, c.memoryBarriers, c.bufferBarriers, 0));
  return recordOf(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const CopyBufferCommand& c) {
  fbs::CmdCopyBufferT r;
  r.command_buffer = cb;
  r.version = 1;
  r.src_buffer = c.src;
  r.dst_buffer = c.dst;
  for (const auto& region : c.regions) r.regions.emplace_back(region.srcOffset, region.dstOffset, region.size);
  return recordOf(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const FillBufferCommand& c) {
  fbs::CmdFillBufferT r;
  r.command_buffer = cb;
  r.dst_buffer = c.dst;
  r.dst_offset = c.offset;
  r.size = c.size;
  r.data = c.data;
  return recordOf(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const UpdateBufferCommand& c) {
  fbs::CmdUpdateBufferT r;
  r.command_buffer = cb;
  r.dst_buffer = c.dst;
  r.dst_offset = c.offset;
  r.data = c.data;
  return recordOf(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const DispatchCommand& c) {
  fbs::CmdDispatchT r;
  r.command_buffer = cb;
  r.group_count_x = c.groupCountX;
  r.group_count_y = c.groupCountY;
  r.group_count_z = c.groupCountZ;
  r.pipeline = c.pipeline;
  r.indirect_buffer = c.indirectBuffer;
  r.indirect_offset = c.indirectOffset;
  for (const auto& b : c.storageBuffers)
    r.storage_buffers.emplace_back(b.set, b.binding, b.arrayElement, uint32_t(b.type), b.buffer, b.offset, b.range,
                                   b.address);
  return recordOf(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const ClusterBuildCommand& c) {
  return recordOf(traces::cluster_commands_to_record(cb, c.parameters.resolved()));
}

fbs::RecordT encode(uint64_t cb, const BuildAccelerationStructureNVCommand& c) {
  fbs::CmdBuildAccelerationStructureNVT r;
  r.command_buffer = cb;
  r.info = nvInfoOf(uint32_t(c.type), c.flags, c.instanceCount, c.geometries);
  r.instance_data = c.instanceData;
  r.instance_offset = c.instanceOffset;
  r.update = c.update == VK_TRUE;
  r.dst = c.dst;
  r.src = c.src;
  r.scratch = c.scratch;
  r.scratch_offset = c.scratchOffset;
  return recordOf(std::move(r));
}

fbs::RecordT encode(uint64_t cb, const CopyMemoryToAccelerationStructureCommand& c) {
  fbs::CmdCopyMemoryToAccelerationStructureT r;
  r.command_buffer = cb;
  r.src_address = c.src;
  r.dst = c.dst;
  r.mode = uint32_t(c.mode);
  return recordOf(std::move(r));
}

// Written by the sink itself: the ticks and the secondaries' blocks depend on the submission.
fbs::RecordT encode(uint64_t, const TimestampWriteCommand&) { return {}; }
fbs::RecordT encode(uint64_t, const ExecuteCommandsCommand&) { return {}; }

}  // namespace

fbs::TraceHeaderT traceHeaderOf(const DeviceRecord& d, uint64_t startTimeUnixNs) {
  fbs::TraceHeaderT header;
  header.device = std::make_unique<fbs::DeviceInfoT>();
  fbs::DeviceInfoT& info = *header.device;
  info.name = d.deviceName;
  info.vendor_id = d.vendorId;
  info.device_id = d.deviceId;
  info.driver_version = d.driverVersion;
  info.api_version = d.apiVersion;
  info.device_type = d.deviceType;
  info.pipeline_cache_uuid = d.pipelineCacheUuid;
  if (d.servedByLayer) {
    // The cluster builds' outputs in this trace were written by clastrace's engine, not by
    // the device's driver: replay compares them with the engine byte for byte.
    info.driver_name = "clastrace engine";
    info.driver_info = "VK_NV_cluster_acceleration_structure served by VK_LAYER_CLASTRACE_capture: cluster "
                       "builds executed by clastrace's CPU engine on the host; the device's driver ran "
                       "everything else";
  } else if (!d.driverName.empty()) {
    info.driver_id = d.driverId;
    info.driver_name = d.driverName;
    info.driver_info = d.driverInfo;
  }
  info.driver_uuid = d.driverUuid;
  info.device_uuid = d.deviceUuid;
  if (d.hasRayTracingPropertiesNV) {
    const auto& rt = d.rayTracingPropertiesNV;
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
  info.timestamp_period_ns = d.timestampPeriod;
  for (const auto& t : d.memoryTypes) info.memory_types.emplace_back(t.propertyFlags, t.heapIndex);
  for (const auto& h : d.memoryHeaps) info.memory_heaps.emplace_back(h.size, h.flags);
  info.enabled_extensions = d.enabledExtensions;
  info.cluster_features = std::make_unique<fbs::ClusterFeaturesT>();
  info.cluster_features->cluster_acceleration_structure_supported = d.clusterProperties.maxTrianglesPerCluster != 0;
  info.cluster_features->cluster_acceleration_structure_enabled = d.clusterFeatureEnabled;
  info.cluster_properties = std::make_unique<fbs::ClusterPropertiesT>();
  auto& p = *info.cluster_properties;
  p.max_vertices_per_cluster = d.clusterProperties.maxVerticesPerCluster;
  p.max_triangles_per_cluster = d.clusterProperties.maxTrianglesPerCluster;
  p.cluster_scratch_byte_alignment = d.clusterProperties.clusterScratchByteAlignment;
  p.cluster_byte_alignment = d.clusterProperties.clusterByteAlignment;
  p.cluster_template_byte_alignment = d.clusterProperties.clusterTemplateByteAlignment;
  p.cluster_bottom_level_byte_alignment = d.clusterProperties.clusterBottomLevelByteAlignment;
  p.cluster_template_bounds_byte_alignment = d.clusterProperties.clusterTemplateBoundsByteAlignment;
  p.max_cluster_geometry_index = d.clusterProperties.maxClusterGeometryIndex;
  header.capture = std::make_unique<fbs::CaptureSettingsT>();
  header.capture->application_name = d.applicationName;
  header.capture->engine_name = d.engineName;
  header.capture->capture_tool = d.servedByLayer ? "clastrace-capture 0.1.0 (serving the extension)"
                                                 : "clastrace-capture 0.1.0";
  header.capture->start_time_unix_ns = startTimeUnixNs;
  header.capture->snapshot_policy = "inputs+outputs";
  return header;
}

fbs::RecordT hostSyncRecordOf(const HostSyncRecord& h) {
  using K = HostSyncRecord::Kind;
  auto first = [&] { return h.handles.empty() ? 0 : h.handles[0]; };
  switch (h.kind) {
    case K::EventSet:
    case K::EventReset:
    case K::EventStatus: {
      fbs::HostEventOpT r;
      r.event = first();
      r.op = h.kind == K::EventSet ? 0 : h.kind == K::EventReset ? 1 : 2;
      r.result = h.result;
      return recordOf(std::move(r));
    }
    case K::FenceWait: {
      fbs::FenceWaitT r;
      r.fences = h.handles;
      r.wait_all = h.waitAll;
      r.timeout = h.timeout;
      r.result = h.result;
      return recordOf(std::move(r));
    }
    case K::FenceReset: {
      fbs::FenceResetT r;
      r.fences = h.handles;
      return recordOf(std::move(r));
    }
    case K::FenceStatus: {
      fbs::FenceStatusT r;
      r.fence = first();
      r.result = h.result;
      return recordOf(std::move(r));
    }
    case K::QueueWaitIdle: {
      fbs::QueueWaitIdleT r;
      r.queue = first();
      r.result = h.result;
      return recordOf(std::move(r));
    }
    case K::DeviceWaitIdle: {
      fbs::DeviceWaitIdleT r;
      r.result = h.result;
      return recordOf(std::move(r));
    }
    case K::SemaphoreSignal:
    case K::SemaphoreWait:
      break;
  }
  fbs::HostSemaphoreOpT r;
  r.op = h.kind == K::SemaphoreSignal ? 0 : 1;
  r.semaphores = h.handles;
  r.values = h.values;
  r.wait_any = !h.waitAll;
  r.timeout = h.timeout;
  r.result = h.result;
  return recordOf(std::move(r));
}

std::unique_ptr<fbs::AccelerationStructureInfoNVT> nvInfoOf(uint32_t type, uint32_t flags, uint32_t instances,
                                                            const std::vector<VkGeometryNV>& geometries) {
  VkAccelerationStructureInfoNV info{VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_INFO_NV};
  info.type = VkAccelerationStructureTypeNV(type);
  info.flags = flags;
  info.instanceCount = instances;
  info.geometryCount = uint32_t(geometries.size());
  info.pGeometries = geometries.data();
  return traces::nv_info_to_record(info);
}

fbs::RecordT commandRecordOf(uint64_t commandBuffer, const RecordedCommand& command) {
  return std::visit([&](const auto& c) { return encode(commandBuffer, c); }, command);
}

fbs::QueueSubmitT queueSubmitOf(const SubmissionRecord& s, uint64_t submissionIndex) {
  fbs::QueueSubmitT submit;
  submit.queue = s.queue;
  submit.queue_family_index = s.queueFamily;
  submit.queue_index = s.queueIndex;
  submit.version = s.synchronization2 ? 2 : 1;
  for (const auto& b : s.batches) {
    auto batch = std::make_unique<fbs::SubmitBatchT>();
    for (const auto& w : b.waits) batch->wait_semaphores.emplace_back(w.semaphore, w.value, w.stageMask, 0);
    batch->command_buffers = b.commandBuffers;
    for (const auto& g : b.signals) batch->signal_semaphores.emplace_back(g.semaphore, g.value, g.stageMask, 0);
    submit.batches.push_back(std::move(batch));
  }
  submit.fence = s.fence;
  submit.submission_index = submissionIndex;
  submit.result = VK_SUCCESS;
  return submit;
}

fbs::RayQueryCheckT rayQueryCheckOf(const RayCheckRecord& c, uint64_t afterSubmission) {
  fbs::RayQueryCheckT r;
  r.acceleration_structure = c.accelerationStructure;
  r.device_handle = c.deviceHandle;
  r.after_submission = afterSubmission;
  for (const NvTracedRay& ray : c.rays)
    r.rays.emplace_back(ray.origin[0], ray.origin[1], ray.origin[2], ray.tMin, ray.direction[0], ray.direction[1],
                        ray.direction[2], ray.tMax, ray.rayFlags, ray.cullMask);
  // NV GLSL has no gl_GeometryIndexEXT: the index comes from the hit record (stride 1), so it
  // is the driver's answer too.
  for (const NvRayHit& h : c.hits)
    r.results.emplace_back(h.hit, h.t, h.instanceCustomIndex, h.instanceId, h.primitiveId,
                           h.hit ? h.geometryIndex : 0xFFFFFFFFu, h.hitKind, h.u, h.v);
  r.label = c.label;
  return r;
}

void collectFindings(uint64_t commandBuffer, size_t index, const ClusterBuildCapture& captured,
                     std::vector<fbs::CaptureFindingT>& out) {
  auto finding = [&](uint8_t severity, const std::string& rule, const std::string& message, int64_t op) {
    fbs::CaptureFindingT r;
    r.command_buffer = commandBuffer;
    r.command_index = uint32_t(index);
    r.op_index = op < 0 || op > int64_t(UINT32_MAX) ? UINT32_MAX : uint32_t(op);
    r.severity = severity;
    r.rule = rule;
    r.message = message;
    out.push_back(std::move(r));
  };
  for (const EngineFindingRecord& f : captured.engineFindings) finding(2, f.rule, f.message, f.opIndex);
  for (const CaptureIssue& i : captured.issues) {
    char where[64];
    std::snprintf(where, sizeof where, " (address 0x%llx, %llu bytes)", (unsigned long long)i.address,
                  (unsigned long long)i.size);
    finding(1, "CLASTRACE-capture-incomplete", i.rule + where, -1);
  }
}

fbs::CaptureFindingT uncapturedCommandFinding(uint64_t commandBuffer, size_t index) {
  fbs::CaptureFindingT f;
  f.command_buffer = commandBuffer;
  f.command_index = uint32_t(index);
  f.op_index = UINT32_MAX;
  f.severity = 1;
  f.rule = "CLASTRACE-capture-incomplete";
  f.message = "the queue never reached this command's pause before the process or the capture ended: "
              "its memory was not captured";
  return f;
}

fbs::CaptureFindingT submissionNoteFinding(const SubmissionRecord::Note& note) {
  fbs::CaptureFindingT f;
  f.command_buffer = note.commandBuffer;
  f.command_index = UINT32_MAX;  // the whole command buffer
  f.op_index = UINT32_MAX;
  f.severity = 1;
  f.rule = note.rule;
  f.message = note.message;
  return f;
}

}  // namespace clastrace::capture
