// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/capture_sink.h"

#include <clastrace/common/hex.h>
#include <clastrace/traces/output_file.h>
#include <nlohmann/json.hpp>

#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <mutex>
#include <span>

namespace clastrace::capture {
namespace {

using nlohmann::json;

std::string hex_bytes(std::span<const uint8_t> bytes) { return common::hex_bytes(bytes); }

json parameters_json(const ClusterCommandParameters& p) {
    const auto& i = p.info;
    json j = {
        {"maxAccelerationStructureCount", i.input.maxAccelerationStructureCount},
        {"flags", i.input.flags},
        {"opType", int(i.input.opType)},
        {"opMode", int(i.input.opMode)},
        {"dstImplicitData", i.dstImplicitData},
        {"scratchData", i.scratchData},
        {"dstAddressesArray",
         {i.dstAddressesArray.deviceAddress, i.dstAddressesArray.stride, i.dstAddressesArray.size}},
        {"dstSizesArray",
         {i.dstSizesArray.deviceAddress, i.dstSizesArray.stride, i.dstSizesArray.size}},
        {"srcInfosArray",
         {i.srcInfosArray.deviceAddress, i.srcInfosArray.stride, i.srcInfosArray.size}},
        {"srcInfosCount", i.srcInfosCount},
        {"addressResolutionFlags", i.addressResolutionFlags},
        {"hasOpInput", p.has_op_input},
    };
    const auto& t = p.triangle_cluster_input;
    j["triangleClusterInput"] = {{"vertexFormat", int(t.vertexFormat)},
                                 {"maxGeometryIndexValue", t.maxGeometryIndexValue},
                                 {"maxClusterUniqueGeometryCount", t.maxClusterUniqueGeometryCount},
                                 {"maxClusterTriangleCount", t.maxClusterTriangleCount},
                                 {"maxClusterVertexCount", t.maxClusterVertexCount},
                                 {"maxTotalTriangleCount", t.maxTotalTriangleCount},
                                 {"maxTotalVertexCount", t.maxTotalVertexCount},
                                 {"minPositionTruncateBitCount", t.minPositionTruncateBitCount}};
    j["bottomLevelInput"] = {{"maxTotalClusterCount", p.bottom_level_input.maxTotalClusterCount},
                             {"maxClusterCountPerAccelerationStructure",
                              p.bottom_level_input.maxClusterCountPerAccelerationStructure}};
    j["moveObjectsInput"] = {{"type", int(p.move_objects_input.type)},
                             {"noMoveOverlap", p.move_objects_input.noMoveOverlap},
                             {"maxMovedBytes", p.move_objects_input.maxMovedBytes}};
    return j;
}

json ranges_json(const std::vector<CapturedRange>& ranges) {
    json list = json::array();
    for (const auto& r : ranges)
        list.push_back({{"role", memory_role_name(r.role)},
                        {"entry", r.entry},
                        {"address", r.address},
                        {"size", r.bytes.size()},
                        {"bytes", hex_bytes(r.bytes.span())}});
    return list;
}

json barriers_json(const std::vector<MemoryBarrier>& memory,
                   const std::vector<BufferBarrier>& buffers) {
    json j = {{"memory", json::array()}, {"buffer", json::array()}};
    for (const auto& b : memory)
        j["memory"].push_back({b.src_stage, b.src_access, b.dst_stage, b.dst_access});
    for (const auto& b : buffers)
        j["buffer"].push_back({{"masks", {b.src_stage, b.src_access, b.dst_stage, b.dst_access}},
                               {"buffer", b.buffer},
                               {"offset", b.offset},
                               {"size", b.size}});
    return j;
}

struct CommandToJson {
    json operator()(const BarrierCommand& c) const {
        return {{"kind", c.synchronization2 ? "PipelineBarrier2" : "PipelineBarrier"},
                {"srcStageMask", c.src_stage_mask},
                {"dstStageMask", c.dst_stage_mask},
                {"dependencyFlags", c.dependency_flags},
                {"barriers", barriers_json(c.memory_barriers, c.buffer_barriers)},
                {"imageBarrierCount", c.image_barrier_count}};
    }
    json operator()(const EventCommand& c) const {
        const char* names[] = {"SetEvent", "ResetEvent", "WaitEvents"};
        std::string kind = names[int(c.kind)];
        if (c.synchronization2) kind += "2";
        return {{"kind", kind},
                {"events", c.events},
                {"srcStageMask", c.src_stage_mask},
                {"dstStageMask", c.dst_stage_mask},
                {"barriers", barriers_json(c.memory_barriers, c.buffer_barriers)}};
    }
    json operator()(const CopyBufferCommand& c) const {
        json regions = json::array();
        for (const auto& r : c.regions) regions.push_back({r.srcOffset, r.dstOffset, r.size});
        return {{"kind", "CopyBuffer"}, {"src", c.src}, {"dst", c.dst}, {"regions", regions}};
    }
    json operator()(const FillBufferCommand& c) const {
        return {{"kind", "FillBuffer"},
                {"dst", c.dst},
                {"offset", c.offset},
                {"size", c.size},
                {"data", c.data}};
    }
    json operator()(const UpdateBufferCommand& c) const {
        return {{"kind", "UpdateBuffer"},
                {"dst", c.dst},
                {"offset", c.offset},
                {"bytes", hex_bytes(c.data)}};
    }
    static json buffers_json(const std::vector<BoundStorageBuffer>& storage_buffers) {
        json buffers = json::array();
        for (const auto& b : storage_buffers)
            buffers.push_back({{"set", b.set},
                               {"binding", b.binding},
                               {"arrayElement", b.array_element},
                               {"type", int(b.type)},
                               {"buffer", b.buffer},
                               {"offset", b.offset},
                               {"range", b.range},
                               {"address", b.address}});
        return buffers;
    }
    static json structures_json(const std::vector<ReachableAccelerationStructure>& reachable) {
        json out = json::array();
        for (const auto& r : reachable)
            out.push_back({{"set", r.set},
                           {"binding", r.binding},
                           {"arrayElement", r.array_element},
                           {"source", uint32_t(r.source)},
                           {"accelerationStructure", r.acceleration_structure},
                           {"address", r.address}});
        return out;
    }
    json operator()(const DispatchCommand& c) const {
        const json buffers = buffers_json(c.storage_buffers);
        return {{"kind", "Dispatch"},
                {"groups", {c.group_count_x, c.group_count_y, c.group_count_z}},
                {"pipeline", c.pipeline},
                {"indirectBuffer", c.indirect_buffer},
                {"indirectOffset", c.indirect_offset},
                {"storageBuffers", buffers},
                {"mayWriteDeviceAddresses", c.may_write_device_addresses},
                {"pauseId", c.pause_id},
                {"rayQuery", c.ray_query},
                {"accelerationStructures", structures_json(c.acceleration_structures)}};
    }
    json operator()(const DrawCommand& c) const {
        return {{"kind", "Draw"},
                {"entryPoint", c.entry_point},
                {"pipeline", c.pipeline},
                {"addressStages", c.address_stages},
                {"rayQueryStages", c.ray_query_stages},
                {"accelerationStructures", structures_json(c.acceleration_structures)}};
    }
    json operator()(const TraceRaysCommand& c) const {
        json tables = json::array();
        for (const VkStridedDeviceAddressRegionKHR& t : c.shader_binding_tables)
            tables.push_back({t.deviceAddress, t.stride, t.size});
        return {{"kind", "TraceRays"},
                {"entryPoint", c.entry_point},
                {"pipeline", c.pipeline},
                {"dimensions", {c.width, c.height, c.depth}},
                {"indirectAddress", c.indirect_address},
                {"shaderBindingTables", tables},
                {"accelerationStructures", structures_json(c.acceleration_structures)},
                {"storageBuffers", buffers_json(c.storage_buffers)},
                {"mayWriteDeviceAddresses", c.may_write_device_addresses},
                {"pauseId", c.pause_id}};
    }
    json operator()(const ClusterBuildCommand& c) const {
        return {{"kind", "BuildClusterAccelerationStructureIndirectNV"},
                {"pauseId", c.pause_id},
                {"executedByLayer", c.executed_by_layer},
                {"parameters", parameters_json(c.parameters)}};
    }
    json operator()(const BuildAccelerationStructureNVCommand& c) const {
        return {{"kind", "BuildAccelerationStructureNV"},
                {"type", int(c.type)},
                {"flags", c.flags},
                {"instanceCount", c.instance_count},
                {"geometryCount", c.geometries.size()},
                {"instanceData", c.instance_data},
                {"instanceOffset", c.instance_offset},
                {"update", c.update},
                {"dst", c.dst},
                {"src", c.src},
                {"scratch", c.scratch},
                {"scratchOffset", c.scratch_offset},
                {"pauseId", c.pause_id}};
    }
    json operator()(const ExecuteCommandsCommand& c) const {
        return {{"kind", "ExecuteCommands"}, {"secondaries", c.secondaries}};
    }
    json operator()(const TimestampWriteCommand& c) const {
        return {{"kind", "WriteTimestamp"}, {"query", c.query}, {"stageMask", c.stage_mask}};
    }
    json operator()(const BuildAccelerationStructuresKHRCommand& c) const {
        json infos = json::array();
        for (const KhrBuildInfo& i : c.infos) {
            json ranges = json::array();
            for (const auto& r : i.ranges)
                ranges.push_back(
                    {r.primitiveCount, r.primitiveOffset, r.firstVertex, r.transformOffset});
            json geometry_types = json::array();
            for (const auto& g : i.geometries) geometry_types.push_back(int(g.geometryType));
            infos.push_back({{"type", int(i.info.type)},
                             {"flags", i.info.flags},
                             {"mode", int(i.info.mode)},
                             {"src", (uint64_t)(i.info.srcAccelerationStructure)},
                             {"dst", (uint64_t)(i.info.dstAccelerationStructure)},
                             {"geometryTypes", geometry_types},
                             {"scratch", i.info.scratchData.deviceAddress},
                             {"ranges", ranges},
                             {"indirectAddress", i.indirect_address},
                             {"indirectStride", i.indirect_stride},
                             {"maxPrimitiveCounts", i.max_primitive_counts}});
        }
        return {{"kind", c.indirect ? "BuildAccelerationStructuresIndirectKHR"
                                    : "BuildAccelerationStructuresKHR"},
                {"infos", infos},
                {"pauseId", c.pause_id}};
    }
    json operator()(const CopyAccelerationStructureCommand& c) const {
        return {{"kind", c.to_memory ? "CopyAccelerationStructureToMemoryKHR"
                         : c.khr     ? "CopyAccelerationStructureKHR"
                                     : "CopyAccelerationStructureNV"},
                {"src", c.src},
                {"dst", c.dst},
                {"dstAddress", c.dst_address},
                {"mode", int(c.mode)},
                {"pauseId", c.pause_id}};
    }
    json operator()(const WriteAccelerationStructuresPropertiesCommand& c) const {
        return {{"kind", c.khr ? "WriteAccelerationStructuresPropertiesKHR"
                               : "WriteAccelerationStructuresPropertiesNV"},
                {"accelerationStructures", c.acceleration_structures},
                {"queryType", int(c.query_type)},
                {"queryPool", c.query_pool},
                {"firstQuery", c.first_query}};
    }
    json operator()(const CopyMemoryToAccelerationStructureCommand& c) const {
        return {{"kind", "CopyMemoryToAccelerationStructureKHR"},
                {"src", c.src},
                {"dst", c.dst},
                {"mode", int(c.mode)},
                {"pauseId", c.pause_id}};
    }
};

json semaphores_json(const std::vector<SemaphoreUse>& uses) {
    json list = json::array();
    for (const auto& s : uses)
        list.push_back(
            {{"semaphore", s.semaphore}, {"value", s.value}, {"stageMask", s.stage_mask}});
    return list;
}

class JsonCaptureSink final : public CaptureSink {
public:
    explicit JsonCaptureSink(std::string path) : path_(std::move(path)) {
        for (const char* key : {"devices",          "memories",
                                "freedMemories",    "buffers",
                                "bindings",         "addresses",
                                "destroyedBuffers", "buildSizes",
                                "commandBuffers",   "resets",
                                "submissions",      "clusterBuilds",
                                "destroyedDevices", "accelerationStructures",
                                "rayChecks",        "hostSync",
                                "presents",         "acquires",
                                "queryPoolResults", "khrBuildSizes"})
            root_[key] = json::array();
    }
    ~JsonCaptureSink() override {  // the application may exit without destroying its device
        std::lock_guard lock(mutex_);
        write_or_report_locked();
    }

    void device_created(const DeviceRecord& d) override {
        const auto& p = d.cluster_properties;
        json types = json::array();
        for (const auto& t : d.memory_types)
            types.push_back({{"propertyFlags", t.propertyFlags}, {"heapIndex", t.heapIndex}});
        add("devices",
            {{"device", d.device},
             {"deviceName", d.device_name},
             {"driverName", d.driver_name},
             {"driverInfo", d.driver_info},
             {"driverUuid", hex_bytes(d.driver_uuid)},
             {"rayTracingHandleSize", d.ray_tracing_properties_nv.shaderGroupHandleSize},
             {"applicationName", d.application_name},
             {"apiVersion", d.api_version},
             {"servedByLayer", d.served_by_layer},
             {"clusterFeatureEnabled", d.cluster_feature_enabled},
             {"memoryTypes", types},
             {"clusterProperties",
              {{"maxVerticesPerCluster", p.maxVerticesPerCluster},
               {"maxTrianglesPerCluster", p.maxTrianglesPerCluster},
               {"clusterScratchByteAlignment", p.clusterScratchByteAlignment},
               {"clusterByteAlignment", p.clusterByteAlignment},
               {"clusterTemplateByteAlignment", p.clusterTemplateByteAlignment},
               {"clusterBottomLevelByteAlignment", p.clusterBottomLevelByteAlignment},
               {"clusterTemplateBoundsByteAlignment", p.clusterTemplateBoundsByteAlignment},
               {"maxClusterGeometryIndex", p.maxClusterGeometryIndex}}}});
    }
    void device_destroyed(uint64_t device) override {
        add("destroyedDevices", device);
        flush();
    }
    void memory_allocated(const MemoryRecord& m) override {
        add("memories", {{"memory", m.memory},
                         {"size", m.size},
                         {"typeIndex", m.type_index},
                         {"propertyFlags", m.property_flags}});
    }
    void memory_freed(uint64_t memory) override { add("freedMemories", memory); }
    void buffer_created(const BufferRecord& b) override {
        add("buffers",
            {{"buffer", b.buffer}, {"size", b.size}, {"usage", b.usage}, {"flags", b.flags}});
    }
    void buffer_bound(const BufferBindingRecord& b) override {
        add("bindings", {{"buffer", b.buffer}, {"memory", b.memory}, {"offset", b.offset}});
    }
    void buffer_address_queried(const BufferAddressRecord& a) override {
        add("addresses", {{"buffer", a.buffer}, {"address", a.address}});
    }
    void buffer_destroyed(uint64_t buffer) override { add("destroyedBuffers", buffer); }
    void build_sizes_queried(const BuildSizesQuery& q) override {
        add("buildSizes", {{"device", q.device},
                           {"input", parameters_json(q.input)},
                           {"answeredByLayer", q.answered_by_layer},
                           {"accelerationStructureSize", q.answer.accelerationStructureSize},
                           {"buildScratchSize", q.answer.buildScratchSize},
                           {"updateScratchSize", q.answer.updateScratchSize}});
    }
    void command_buffer_recorded(const RecordedCommandBuffer& cb) override {
        json commands = json::array();
        json timestamps =
            json::array();  // the layer's own, kept apart so command indices are the application's
        for (const auto& c : cb.commands) {
            if (const auto* t = std::get_if<TimestampWriteCommand>(&c)) {
                timestamps.push_back({{"afterCommand", commands.size()},
                                      {"query", t->query},
                                      {"stageMask", t->stage_mask},
                                      {"readPauseId", t->read_pause_id}});
                continue;
            }
            commands.push_back(std::visit(CommandToJson{}, c));
        }
        add("commandBuffers", {{"commandBuffer", cb.command_buffer},
                               {"usage", cb.usage},
                               {"secondary", cb.secondary},
                               {"commands", commands},
                               {"timestamps", timestamps}});
    }
    void command_buffer_reset(uint64_t command_buffer) override { add("resets", command_buffer); }
    void query_pool_results_read(const QueryPoolResultsRecord& q) override {
        add("queryPoolResults", {{"queryPool", q.query_pool},
                                 {"firstQuery", q.first_query},
                                 {"values", q.values},
                                 {"result", q.result}});
    }
    void khr_build_sizes_queried(const KhrBuildSizesQuery& q) override {
        add("khrBuildSizes", {{"buildType", int(q.build_type)},
                              {"type", int(q.info.info.type)},
                              {"geometryCount", q.info.geometries.size()},
                              {"maxPrimitiveCounts", q.max_primitive_counts},
                              {"accelerationStructureSize", q.answer.accelerationStructureSize},
                              {"buildScratchSize", q.answer.buildScratchSize},
                              {"updateScratchSize", q.answer.updateScratchSize}});
    }
    void queue_submitted(const SubmissionRecord& s) override {
        json batches = json::array();
        for (const auto& b : s.batches)
            batches.push_back({{"waits", semaphores_json(b.waits)},
                               {"commandBuffers", b.command_buffers},
                               {"signals", semaphores_json(b.signals)}});
        json notes = json::array();
        for (const auto& n : s.notes)
            notes.push_back(
                {{"commandBuffer", n.command_buffer}, {"rule", n.rule}, {"message", n.message}});
        add("submissions", {{"index", s.index},
                            {"queue", s.queue},
                            {"synchronization2", s.synchronization2},
                            {"batches", batches},
                            {"fence", s.fence},
                            {"notes", notes}});
    }
    void cluster_build_captured(ClusterBuildCapture c) override {
        if (c.complete) std::exchange(c.complete, nullptr)(c);  // a readable dump: finished at once
        if (c.kind == CapturedCommandKind::kTimestamps) {  // a readback, not a build: listed apart
            add("timestampReads", {{"pauseId", c.pause_id},
                                   {"submissionIndex", c.submission_index},
                                   {"commandBuffer", c.command_buffer},
                                   {"ticks", c.timestamp_ticks},
                                   {"valid", c.timestamp_valid}});
            return;
        }
        if (c.kind == CapturedCommandKind::kDeviceAddressWrites) {  // exact mode, per execution
            add("deviceAddressWrites", {{"pauseId", c.pause_id},
                                        {"submissionIndex", c.submission_index},
                                        {"commandBuffer", c.command_buffer},
                                        {"writes", ranges_json(c.outputs)},
                                        {"comparedBytes", c.compared_bytes},
                                        {"pauseMilliseconds", c.pause_milliseconds}});
            return;
        }
        json issues = json::array();
        for (const auto& i : c.issues)
            issues.push_back({{"address", i.address}, {"size", i.size}, {"rule", i.rule}});
        json driver_bvh = json::array();
        for (const auto& d : c.driver_bvh)
            driver_bvh.push_back({{"address", d.address}, {"size", d.size}});
        json findings = json::array();
        for (const auto& f : c.engine_findings)
            findings.push_back({{"rule", f.rule},
                                {"message", f.message},
                                {"opIndex", f.op_index},
                                {"address", f.address}});
        add("clusterBuilds", {{"kind", int(c.kind)},
                              {"pauseId", c.pause_id},
                              {"submissionIndex", c.submission_index},
                              {"commandBuffer", c.command_buffer},
                              {"parameters", parameters_json(c.parameters)},
                              {"executedCount", c.executed_count},
                              {"inputs", ranges_json(c.inputs)},
                              {"outputs", ranges_json(c.outputs)},
                              {"issues", issues},
                              {"executedByEngine", c.executed_by_engine},
                              {"engineFindings", findings},
                              {"driverBvh", driver_bvh},
                              {"implicitObjectRoom", c.implicit_object_room},
                              {"pauseMilliseconds", c.pause_milliseconds}});
    }
    void acceleration_structure_created(const AccelerationStructureRecord& a) override {
        add("accelerationStructures", {{"event", "create"},
                                       {"accelerationStructure", a.acceleration_structure},
                                       {"khr", a.khr},
                                       {"type", a.type},
                                       {"buffer", a.buffer},
                                       {"offset", a.offset},
                                       {"size", a.size},
                                       {"instanceCount", a.instance_count},
                                       {"geometryCount", a.geometries.size()}});
    }
    void acceleration_structure_bound(const AccelerationStructureBindingRecord& b) override {
        add("accelerationStructures", {{"event", "bind"},
                                       {"accelerationStructure", b.acceleration_structure},
                                       {"memory", b.memory},
                                       {"offset", b.offset}});
    }
    void acceleration_structure_address_queried(
        const AccelerationStructureAddressRecord& a) override {
        add("accelerationStructures", {{"event", "address"},
                                       {"accelerationStructure", a.acceleration_structure},
                                       {"address", a.address}});
    }
    void acceleration_structure_memory_requirements(
        const AccelerationStructureMemoryRequirementsRecord& m) override {
        add("accelerationStructures", {{"event", "memoryRequirements"},
                                       {"accelerationStructure", m.acceleration_structure},
                                       {"type", m.type},
                                       {"size", m.size},
                                       {"alignment", m.alignment}});
    }
    void acceleration_structure_destroyed(uint64_t as) override {
        add("accelerationStructures", {{"event", "destroy"}, {"accelerationStructure", as}});
    }
    void ray_query_checked(const RayCheckRecord& c) override {
        size_t hits = 0;
        json first_hits = json::array();
        for (const NvRayHit& h : c.hits) {
            hits += h.hit != 0;
            if (h.hit && first_hits.size() < 8)
                first_hits.push_back({{"t", h.t},
                                      {"customIndex", h.instance_custom_index},
                                      {"instanceId", h.instance_id},
                                      {"primitiveId", h.primitive_id},
                                      {"geometryIndex", h.geometry_index},
                                      {"hitKind", h.hit_kind},
                                      {"u", h.u},
                                      {"v", h.v}});
        }
        add("rayChecks", {{"accelerationStructure", c.acceleration_structure},
                          {"deviceHandle", c.device_handle},
                          {"submissionIndex", c.submission_index},
                          {"rays", c.rays.size()},
                          {"hits", hits},
                          {"firstHits", first_hits},
                          {"label", c.label}});
    }
    void host_synchronized(const HostSyncRecord& h) override {
        static const char* const kInds[] = {"EventSet",      "EventReset",     "EventStatus",
                                            "FenceWait",     "FenceReset",     "FenceStatus",
                                            "QueueWaitIdle", "DeviceWaitIdle", "SemaphoreSignal",
                                            "SemaphoreWait"};
        add("hostSync", {{"kind", kInds[int(h.kind)]},
                         {"handles", h.handles},
                         {"values", h.values},
                         {"waitAll", h.wait_all},
                         {"timeout", h.timeout},
                         {"result", h.result}});
    }
    void queue_presented(const PresentRecord& p) override {
        add("presents", {{"queue", p.queue},
                         {"frame", p.frame},
                         {"waitSemaphores", p.wait_semaphores},
                         {"swapchains", p.swapchains},
                         {"imageIndices", p.image_indices},
                         {"result", p.result}});
    }
    void frame_boundary_marked(const FrameBoundaryRecord& b) override {
        add("frameBoundaries", {{"queue", b.queue},
                                {"carrier", uint32_t(b.carrier)},
                                {"submission", b.submission},
                                {"batch", b.batch},
                                {"flags", b.flags},
                                {"frameId", b.frame_id},
                                {"frame", b.frame},
                                {"images", b.images},
                                {"buffers", b.buffers},
                                {"tagName", b.tag_name},
                                {"tagSize", b.tag.size()}});
    }
    void pre_range_state_written(const PreRangeStateRecord& m) override {
        add("preRangeStates", {{"queue", m.queue},
                               {"beforeFrame", m.first_frame},
                               {"preludeSubmission", m.prelude_submission},
                               {"structures", m.structures},
                               {"commands", m.commands},
                               {"clusterCommands", m.cluster_commands},
                               {"inputBytes", m.bytes}});
    }
    void image_acquired(const AcquireRecord& a) override {
        add("acquires", {{"swapchain", a.swapchain},
                         {"timeout", a.timeout},
                         {"semaphore", a.semaphore},
                         {"fence", a.fence},
                         {"imageIndex", a.image_index},
                         {"result", a.result},
                         {"deviceMask", a.device_mask}});
    }
    void flush() override {
        std::lock_guard lock(mutex_);
        write_or_report_locked();
    }
    bool active() const override { return !failed_; }

    // One message for the first failed write; from then on the capture stops (active() false).
    void write_or_report_locked() {
        if (failed_) return;
        std::string error;
        // Names and labels the application gave need not be UTF-8: each ill-formed sequence becomes
        // U+FFFD (traces::valid_utf8's rule), where the default handler would throw in the application.
        if (traces::write_output_file(path_,
                                      root_.dump(1, ' ', false, json::error_handler_t::replace),
                                      &error))
            return;
        failed_ = true;
        std::fprintf(stderr,
                     "clastrace: capture stopped: %s; the application continues without capture\n",
                     error.c_str());
    }

private:
    void add(const char* key, json value) {
        std::lock_guard lock(mutex_);
        root_[key].push_back(std::move(value));
    }

    std::mutex mutex_;
    std::string path_;
    json root_;
    std::atomic<bool> failed_{false};
};

}  // namespace

std::unique_ptr<CaptureSink> make_json_capture_sink(const std::string& path, std::string& error) {
    // Checked without creating or emptying anything: the dump replaces the file whole when written.
    if (!traces::probe_output(path, &error)) return nullptr;
    return std::make_unique<JsonCaptureSink>(path);
}

}  // namespace clastrace::capture
