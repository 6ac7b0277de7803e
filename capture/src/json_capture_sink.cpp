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

std::string hexBytes(std::span<const uint8_t> bytes) { return common::hex_bytes(bytes); }

json parametersJson(const ClusterCommandParameters& p) {
  const auto& i = p.info;
  json j = {
      {"maxAccelerationStructureCount", i.input.maxAccelerationStructureCount},
      {"flags", i.input.flags},
      {"opType", int(i.input.opType)},
      {"opMode", int(i.input.opMode)},
      {"dstImplicitData", i.dstImplicitData},
      {"scratchData", i.scratchData},
      {"dstAddressesArray", {i.dstAddressesArray.deviceAddress, i.dstAddressesArray.stride, i.dstAddressesArray.size}},
      {"dstSizesArray", {i.dstSizesArray.deviceAddress, i.dstSizesArray.stride, i.dstSizesArray.size}},
      {"srcInfosArray", {i.srcInfosArray.deviceAddress, i.srcInfosArray.stride, i.srcInfosArray.size}},
      {"srcInfosCount", i.srcInfosCount},
      {"addressResolutionFlags", i.addressResolutionFlags},
      {"hasOpInput", p.hasOpInput},
  };
  const auto& t = p.triangleClusterInput;
  j["triangleClusterInput"] = {{"vertexFormat", int(t.vertexFormat)},
                               {"maxGeometryIndexValue", t.maxGeometryIndexValue},
                               {"maxClusterUniqueGeometryCount", t.maxClusterUniqueGeometryCount},
                               {"maxClusterTriangleCount", t.maxClusterTriangleCount},
                               {"maxClusterVertexCount", t.maxClusterVertexCount},
                               {"maxTotalTriangleCount", t.maxTotalTriangleCount},
                               {"maxTotalVertexCount", t.maxTotalVertexCount},
                               {"minPositionTruncateBitCount", t.minPositionTruncateBitCount}};
  j["bottomLevelInput"] = {{"maxTotalClusterCount", p.bottomLevelInput.maxTotalClusterCount},
                           {"maxClusterCountPerAccelerationStructure",
                            p.bottomLevelInput.maxClusterCountPerAccelerationStructure}};
  j["moveObjectsInput"] = {{"type", int(p.moveObjectsInput.type)},
                           {"noMoveOverlap", p.moveObjectsInput.noMoveOverlap},
                           {"maxMovedBytes", p.moveObjectsInput.maxMovedBytes}};
  return j;
}

json rangesJson(const std::vector<CapturedRange>& ranges) {
  json list = json::array();
  for (const auto& r : ranges)
    list.push_back({{"role", memoryRoleName(r.role)}, {"entry", r.entry}, {"address", r.address},
                    {"size", r.bytes.size()}, {"bytes", hexBytes(r.bytes.span())}});
  return list;
}

json barriersJson(const std::vector<MemoryBarrier>& memory, const std::vector<BufferBarrier>& buffers) {
  json j = {{"memory", json::array()}, {"buffer", json::array()}};
  for (const auto& b : memory)
    j["memory"].push_back({b.srcStage, b.srcAccess, b.dstStage, b.dstAccess});
  for (const auto& b : buffers)
    j["buffer"].push_back({{"masks", {b.srcStage, b.srcAccess, b.dstStage, b.dstAccess}},
                           {"buffer", b.buffer}, {"offset", b.offset}, {"size", b.size}});
  return j;
}

struct CommandToJson {
  json operator()(const BarrierCommand& c) const {
    return {{"kind", c.synchronization2 ? "PipelineBarrier2" : "PipelineBarrier"},
            {"srcStageMask", c.srcStageMask}, {"dstStageMask", c.dstStageMask},
            {"dependencyFlags", c.dependencyFlags}, {"barriers", barriersJson(c.memoryBarriers, c.bufferBarriers)},
            {"imageBarrierCount", c.imageBarrierCount}};
  }
  json operator()(const EventCommand& c) const {
    const char* names[] = {"SetEvent", "ResetEvent", "WaitEvents"};
    std::string kind = names[int(c.kind)];
    if (c.synchronization2) kind += "2";
    return {{"kind", kind}, {"events", c.events}, {"srcStageMask", c.srcStageMask},
            {"dstStageMask", c.dstStageMask}, {"barriers", barriersJson(c.memoryBarriers, c.bufferBarriers)}};
  }
  json operator()(const CopyBufferCommand& c) const {
    json regions = json::array();
    for (const auto& r : c.regions) regions.push_back({r.srcOffset, r.dstOffset, r.size});
    return {{"kind", "CopyBuffer"}, {"src", c.src}, {"dst", c.dst}, {"regions", regions}};
  }
  json operator()(const FillBufferCommand& c) const {
    return {{"kind", "FillBuffer"}, {"dst", c.dst}, {"offset", c.offset}, {"size", c.size}, {"data", c.data}};
  }
  json operator()(const UpdateBufferCommand& c) const {
    return {{"kind", "UpdateBuffer"}, {"dst", c.dst}, {"offset", c.offset}, {"bytes", hexBytes(c.data)}};
  }
  json operator()(const DispatchCommand& c) const {
    json buffers = json::array();
    for (const auto& b : c.storageBuffers)
      buffers.push_back({{"set", b.set}, {"binding", b.binding}, {"arrayElement", b.arrayElement},
                         {"type", int(b.type)}, {"buffer", b.buffer}, {"offset", b.offset}, {"range", b.range},
                         {"address", b.address}});
    return {{"kind", "Dispatch"}, {"groups", {c.groupCountX, c.groupCountY, c.groupCountZ}}, {"pipeline", c.pipeline},
            {"indirectBuffer", c.indirectBuffer}, {"indirectOffset", c.indirectOffset}, {"storageBuffers", buffers}};
  }
  json operator()(const ClusterBuildCommand& c) const {
    return {{"kind", "BuildClusterAccelerationStructureIndirectNV"}, {"pauseId", c.pauseId},
            {"executedByLayer", c.executedByLayer}, {"parameters", parametersJson(c.parameters)}};
  }
  json operator()(const BuildAccelerationStructureNVCommand& c) const {
    return {{"kind", "BuildAccelerationStructureNV"}, {"type", int(c.type)}, {"flags", c.flags},
            {"instanceCount", c.instanceCount}, {"geometryCount", c.geometries.size()},
            {"instanceData", c.instanceData}, {"instanceOffset", c.instanceOffset}, {"update", c.update},
            {"dst", c.dst}, {"src", c.src}, {"scratch", c.scratch}, {"scratchOffset", c.scratchOffset},
            {"pauseId", c.pauseId}};
  }
  json operator()(const ExecuteCommandsCommand& c) const {
    return {{"kind", "ExecuteCommands"}, {"secondaries", c.secondaries}};
  }
  json operator()(const TimestampWriteCommand& c) const {
    return {{"kind", "WriteTimestamp"}, {"query", c.query}, {"stageMask", c.stageMask}};
  }
  json operator()(const CopyMemoryToAccelerationStructureCommand& c) const {
    return {{"kind", "CopyMemoryToAccelerationStructureKHR"}, {"src", c.src}, {"dst", c.dst}, {"mode", int(c.mode)},
            {"pauseId", c.pauseId}};
  }
};

json semaphoresJson(const std::vector<SemaphoreUse>& uses) {
  json list = json::array();
  for (const auto& s : uses) list.push_back({{"semaphore", s.semaphore}, {"value", s.value}, {"stageMask", s.stageMask}});
  return list;
}

class JsonCaptureSink final : public CaptureSink {
 public:
  explicit JsonCaptureSink(std::string path) : path_(std::move(path)) {
    for (const char* key : {"devices", "memories", "freedMemories", "buffers", "bindings", "addresses",
                            "destroyedBuffers", "buildSizes", "commandBuffers", "resets", "submissions",
                            "clusterBuilds", "destroyedDevices", "accelerationStructures", "rayChecks", "hostSync", "presents", "acquires"})
      root_[key] = json::array();
  }
  ~JsonCaptureSink() override {  // the application may exit without destroying its device
    std::lock_guard lock(mutex_);
    writeOrReportLocked();
  }

  void deviceCreated(const DeviceRecord& d) override {
    const auto& p = d.clusterProperties;
    json types = json::array();
    for (const auto& t : d.memoryTypes) types.push_back({{"propertyFlags", t.propertyFlags}, {"heapIndex", t.heapIndex}});
    add("devices", {{"device", d.device}, {"deviceName", d.deviceName}, {"driverName", d.driverName},
                    {"driverInfo", d.driverInfo}, {"driverUuid", hexBytes(d.driverUuid)},
                    {"rayTracingHandleSize", d.rayTracingPropertiesNV.shaderGroupHandleSize}, {"applicationName", d.applicationName}, {"apiVersion", d.apiVersion},
                    {"servedByLayer", d.servedByLayer}, {"clusterFeatureEnabled", d.clusterFeatureEnabled},
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
  void deviceDestroyed(uint64_t device) override {
    add("destroyedDevices", device);
    flush();
  }
  void memoryAllocated(const MemoryRecord& m) override {
    add("memories", {{"memory", m.memory}, {"size", m.size}, {"typeIndex", m.typeIndex}, {"propertyFlags", m.propertyFlags}});
  }
  void memoryFreed(uint64_t memory) override { add("freedMemories", memory); }
  void bufferCreated(const BufferRecord& b) override {
    add("buffers", {{"buffer", b.buffer}, {"size", b.size}, {"usage", b.usage}, {"flags", b.flags}});
  }
  void bufferBound(const BufferBindingRecord& b) override {
    add("bindings", {{"buffer", b.buffer}, {"memory", b.memory}, {"offset", b.offset}});
  }
  void bufferAddressQueried(const BufferAddressRecord& a) override {
    add("addresses", {{"buffer", a.buffer}, {"address", a.address}});
  }
  void bufferDestroyed(uint64_t buffer) override { add("destroyedBuffers", buffer); }
  void buildSizesQueried(const BuildSizesQuery& q) override {
    add("buildSizes", {{"device", q.device}, {"input", parametersJson(q.input)}, {"answeredByLayer", q.answeredByLayer},
                       {"accelerationStructureSize", q.answer.accelerationStructureSize},
                       {"buildScratchSize", q.answer.buildScratchSize},
                       {"updateScratchSize", q.answer.updateScratchSize}});
  }
  void commandBufferRecorded(const RecordedCommandBuffer& cb) override {
    json commands = json::array();
    json timestamps = json::array();  // the layer's own, kept apart so command indices are the application's
    for (const auto& c : cb.commands) {
      if (const auto* t = std::get_if<TimestampWriteCommand>(&c)) {
        timestamps.push_back({{"afterCommand", commands.size()}, {"query", t->query}, {"stageMask", t->stageMask},
                              {"readPauseId", t->readPauseId}});
        continue;
      }
      commands.push_back(std::visit(CommandToJson{}, c));
    }
    add("commandBuffers", {{"commandBuffer", cb.commandBuffer}, {"usage", cb.usage}, {"secondary", cb.secondary},
                           {"commands", commands},
                           {"timestamps", timestamps}});
  }
  void commandBufferReset(uint64_t commandBuffer) override { add("resets", commandBuffer); }
  void queueSubmitted(const SubmissionRecord& s) override {
    json batches = json::array();
    for (const auto& b : s.batches)
      batches.push_back({{"waits", semaphoresJson(b.waits)}, {"commandBuffers", b.commandBuffers},
                         {"signals", semaphoresJson(b.signals)}});
    json notes = json::array();
    for (const auto& n : s.notes) notes.push_back({{"commandBuffer", n.commandBuffer}, {"rule", n.rule}, {"message", n.message}});
    add("submissions", {{"index", s.index}, {"queue", s.queue}, {"synchronization2", s.synchronization2},
                        {"batches", batches}, {"fence", s.fence}, {"notes", notes}});
  }
  void clusterBuildCaptured(ClusterBuildCapture c) override {
    if (c.complete) std::exchange(c.complete, nullptr)(c);  // a readable dump: finished at once
    if (c.kind == CapturedCommandKind::Timestamps) {  // a readback, not a build: listed apart
      add("timestampReads", {{"pauseId", c.pauseId}, {"submissionIndex", c.submissionIndex},
                             {"commandBuffer", c.commandBuffer}, {"ticks", c.timestampTicks},
                             {"valid", c.timestampValid}});
      return;
    }
    json issues = json::array();
    for (const auto& i : c.issues) issues.push_back({{"address", i.address}, {"size", i.size}, {"rule", i.rule}});
    json findings = json::array();
    for (const auto& f : c.engineFindings)
      findings.push_back({{"rule", f.rule}, {"message", f.message}, {"opIndex", f.opIndex}, {"address", f.address}});
    add("clusterBuilds", {{"kind", int(c.kind)}, {"pauseId", c.pauseId}, {"submissionIndex", c.submissionIndex},
                          {"commandBuffer", c.commandBuffer}, {"parameters", parametersJson(c.parameters)},
                          {"executedCount", c.executedCount}, {"inputs", rangesJson(c.inputs)},
                          {"outputs", rangesJson(c.outputs)}, {"issues", issues},
                          {"executedByEngine", c.executedByEngine}, {"engineFindings", findings},
                          {"pauseMilliseconds", c.pauseMilliseconds}});
  }
  void accelerationStructureCreated(const AccelerationStructureRecord& a) override {
    add("accelerationStructures", {{"event", "create"}, {"accelerationStructure", a.accelerationStructure},
                                   {"khr", a.khr}, {"type", a.type}, {"buffer", a.buffer}, {"offset", a.offset},
                                   {"size", a.size}, {"instanceCount", a.instanceCount},
                                   {"geometryCount", a.geometries.size()}});
  }
  void accelerationStructureBound(const AccelerationStructureBindingRecord& b) override {
    add("accelerationStructures", {{"event", "bind"}, {"accelerationStructure", b.accelerationStructure},
                                   {"memory", b.memory}, {"offset", b.offset}});
  }
  void accelerationStructureAddressQueried(const AccelerationStructureAddressRecord& a) override {
    add("accelerationStructures",
        {{"event", "address"}, {"accelerationStructure", a.accelerationStructure}, {"address", a.address}});
  }
  void accelerationStructureMemoryRequirements(const AccelerationStructureMemoryRequirementsRecord& m) override {
    add("accelerationStructures", {{"event", "memoryRequirements"}, {"accelerationStructure", m.accelerationStructure},
                                   {"type", m.type}, {"size", m.size}, {"alignment", m.alignment}});
  }
  void accelerationStructureDestroyed(uint64_t as) override {
    add("accelerationStructures", {{"event", "destroy"}, {"accelerationStructure", as}});
  }
  void rayQueryChecked(const RayCheckRecord& c) override {
    size_t hits = 0;
    json firstHits = json::array();
    for (const NvRayHit& h : c.hits) {
      hits += h.hit != 0;
      if (h.hit && firstHits.size() < 8)
        firstHits.push_back({{"t", h.t}, {"customIndex", h.instanceCustomIndex}, {"instanceId", h.instanceId},
                             {"primitiveId", h.primitiveId}, {"geometryIndex", h.geometryIndex},
                             {"hitKind", h.hitKind}, {"u", h.u}, {"v", h.v}});
    }
    add("rayChecks", {{"accelerationStructure", c.accelerationStructure}, {"deviceHandle", c.deviceHandle},
                      {"submissionIndex", c.submissionIndex}, {"rays", c.rays.size()}, {"hits", hits},
                      {"firstHits", firstHits}, {"label", c.label}});
  }
  void hostSynchronized(const HostSyncRecord& h) override {
    static const char* const kinds[] = {"EventSet",      "EventReset",     "EventStatus",     "FenceWait",
                                        "FenceReset",    "FenceStatus",    "QueueWaitIdle",   "DeviceWaitIdle",
                                        "SemaphoreSignal", "SemaphoreWait"};
    add("hostSync", {{"kind", kinds[int(h.kind)]}, {"handles", h.handles}, {"values", h.values},
                     {"waitAll", h.waitAll}, {"timeout", h.timeout}, {"result", h.result}});
  }
  void queuePresented(const PresentRecord& p) override {
    add("presents", {{"queue", p.queue}, {"frame", p.frame}, {"waitSemaphores", p.waitSemaphores},
                     {"swapchains", p.swapchains}, {"imageIndices", p.imageIndices}, {"result", p.result}});
  }
  void imageAcquired(const AcquireRecord& a) override {
    add("acquires", {{"swapchain", a.swapchain}, {"timeout", a.timeout}, {"semaphore", a.semaphore},
                     {"fence", a.fence}, {"imageIndex", a.imageIndex}, {"result", a.result},
                     {"deviceMask", a.deviceMask}});
  }
  void flush() override {
    std::lock_guard lock(mutex_);
    writeOrReportLocked();
  }
  bool active() const override { return !failed_; }

  // One message for the first failed write; from then on the capture stops (active() false).
  void writeOrReportLocked() {
    if (failed_) return;
    std::string error;
    // Names and labels the application gave need not be UTF-8: each ill-formed sequence becomes
    // U+FFFD (traces::valid_utf8's rule), where the default handler would throw in the application.
    if (traces::write_output_file(path_, root_.dump(1, ' ', false, json::error_handler_t::replace), &error)) return;
    failed_ = true;
    std::fprintf(stderr, "clastrace: capture stopped: %s; the application continues without capture\n",
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

std::unique_ptr<CaptureSink> makeJsonCaptureSink(const std::string& path, std::string& error) {
  // Checked without creating or emptying anything: the dump replaces the file whole when written.
  if (!traces::probe_output(path, &error)) return nullptr;
  return std::make_unique<JsonCaptureSink>(path);
}

}  // namespace clastrace::capture
