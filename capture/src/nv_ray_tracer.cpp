#include "clastrace/capture/nv_ray_tracer.h"

#include <cstring>
#include <functional>

// SPIR-V compiled from capture/shaders at build time (glslangValidator --vn).
#include "ray_check_rchit.h"
#include "ray_check_rgen.h"
#include "ray_check_rint.h"
#include "ray_check_rmiss.h"

namespace clastrace::capture {

const char* const kNvRayCheckRule =
    "clastrace-ray-check/1: traceNV(flags, mask, sbt offset 0, stride 1, miss 0); triangles: the driver's "
    "intersection, hit_kind 0xFE front / 0xFF back, barycentrics (u, v); AABBs: intersection shader slab test "
    "in object space against the primitive's box, t = max(entry, t_min) if t <= exit, hit_kind 0, (u, v) = 0; "
    "closest hit kept; no any-hit shader";

namespace {

#define CLASTRACE_TRACER_FUNCTIONS(X) \
  X(CreateDescriptorSetLayout)        \
  X(DestroyDescriptorSetLayout)       \
  X(CreatePipelineLayout)             \
  X(DestroyPipelineLayout)            \
  X(CreateShaderModule)               \
  X(DestroyShaderModule)              \
  X(CreateRayTracingPipelinesNV)      \
  X(DestroyPipeline)                  \
  X(GetRayTracingShaderGroupHandlesNV) \
  X(CreateBuffer)                     \
  X(DestroyBuffer)                    \
  X(GetBufferMemoryRequirements)      \
  X(AllocateMemory)                   \
  X(FreeMemory)                       \
  X(BindBufferMemory)                 \
  X(MapMemory)                        \
  X(CreateDescriptorPool)             \
  X(DestroyDescriptorPool)            \
  X(AllocateDescriptorSets)           \
  X(UpdateDescriptorSets)             \
  X(CreateCommandPool)                \
  X(DestroyCommandPool)               \
  X(AllocateCommandBuffers)           \
  X(BeginCommandBuffer)               \
  X(EndCommandBuffer)                 \
  X(CmdPipelineBarrier)               \
  X(CmdBindPipeline)                  \
  X(CmdBindDescriptorSets)            \
  X(CmdTraceRaysNV)                   \
  X(CreateFence)                      \
  X(DestroyFence)                     \
  X(QueueSubmit)                      \
  X(WaitForFences)

struct Functions {
#define CLASTRACE_DECLARE(name) PFN_vk##name name = nullptr;
  CLASTRACE_TRACER_FUNCTIONS(CLASTRACE_DECLARE)
#undef CLASTRACE_DECLARE
};

struct HostBuffer {
  VkBuffer buffer = VK_NULL_HANDLE;
  VkDeviceMemory memory = VK_NULL_HANDLE;
  void* mapped = nullptr;
  VkDeviceSize size = 0;
};

// Everything one trace creates, destroyed in reverse order whatever happened.
struct Session {
  const NvRayTracerContext& context;
  Functions f;
  std::vector<std::function<void()>> cleanup;
  std::string error;

  explicit Session(const NvRayTracerContext& c) : context(c) {}
  ~Session() {
    for (auto it = cleanup.rbegin(); it != cleanup.rend(); ++it) (*it)();
  }
  VkDevice device() const { return context.device; }

  bool load() {
#define CLASTRACE_LOAD(name)                                                          \
  f.name = (PFN_vk##name)context.getDeviceProcAddr(context.device, "vk" #name);       \
  if (!f.name) {                                                                      \
    error = "the device has no vk" #name;                                             \
    return false;                                                                     \
  }
    CLASTRACE_TRACER_FUNCTIONS(CLASTRACE_LOAD)
#undef CLASTRACE_LOAD
    return true;
  }

  bool check(VkResult result, const char* what) {
    if (result == VK_SUCCESS) return true;
    error = std::string(what) + " failed with VkResult " + std::to_string(int(result));
    return false;
  }

  bool hostBuffer(VkDeviceSize size, VkBufferUsageFlags usage, HostBuffer& out) {
    out.size = size ? size : 16;
    VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
    info.size = out.size;
    info.usage = usage;
    info.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
    if (!check(f.CreateBuffer(device(), &info, nullptr, &out.buffer), "vkCreateBuffer")) return false;
    VkBuffer buffer = out.buffer;
    cleanup.push_back([this, buffer] { f.DestroyBuffer(device(), buffer, nullptr); });
    VkMemoryRequirements requirements;
    f.GetBufferMemoryRequirements(device(), out.buffer, &requirements);
    const VkMemoryPropertyFlags wanted = VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
    uint32_t type = UINT32_MAX;
    for (uint32_t i = 0; i < context.memoryProperties.memoryTypeCount && type == UINT32_MAX; ++i)
      if ((requirements.memoryTypeBits & (1u << i)) &&
          (context.memoryProperties.memoryTypes[i].propertyFlags & wanted) == wanted)
        type = i;
    if (type == UINT32_MAX) {
      error = "no host-visible coherent memory type for the ray check's buffers";
      return false;
    }
    VkMemoryAllocateInfo allocate{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
    allocate.allocationSize = requirements.size;
    allocate.memoryTypeIndex = type;
    if (!check(f.AllocateMemory(device(), &allocate, nullptr, &out.memory), "vkAllocateMemory")) return false;
    VkDeviceMemory memory = out.memory;
    cleanup.push_back([this, memory] { f.FreeMemory(device(), memory, nullptr); });  // unmaps too
    if (!check(f.BindBufferMemory(device(), out.buffer, out.memory, 0), "vkBindBufferMemory")) return false;
    if (!check(f.MapMemory(device(), out.memory, 0, VK_WHOLE_SIZE, 0, &out.mapped), "vkMapMemory")) return false;
    std::memset(out.mapped, 0, out.size);
    return true;
  }

  template <typename T>
  bool upload(const std::vector<T>& values, VkBufferUsageFlags usage, HostBuffer& out) {
    if (!hostBuffer(values.size() * sizeof(T), usage, out)) return false;
    if (!values.empty()) std::memcpy(out.mapped, values.data(), values.size() * sizeof(T));
    return true;
  }

  bool shader(const uint32_t* code, size_t bytes, VkShaderModule& out) {
    VkShaderModuleCreateInfo info{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
    info.codeSize = bytes;
    info.pCode = code;
    if (!check(f.CreateShaderModule(device(), &info, nullptr, &out), "vkCreateShaderModule")) return false;
    VkShaderModule module = out;
    cleanup.push_back([this, module] { f.DestroyShaderModule(device(), module, nullptr); });
    return true;
  }
};

VkDeviceSize alignUp(VkDeviceSize value, VkDeviceSize alignment) {
  return alignment ? (value + alignment - 1) / alignment * alignment : value;
}

// The pipeline's resources: one descriptor set layout (top level, rays, hits, instance table,
// geometry table, boxes) and the pipeline layout over it.
struct RayCheckLayout {
  VkDescriptorSetLayout setLayout = VK_NULL_HANDLE;
  VkPipelineLayout pipelineLayout = VK_NULL_HANDLE;
};

bool createRayCheckLayout(Session& s, RayCheckLayout& out) {
  const VkShaderStageFlags stages = VK_SHADER_STAGE_RAYGEN_BIT_NV | VK_SHADER_STAGE_MISS_BIT_NV |
                                    VK_SHADER_STAGE_CLOSEST_HIT_BIT_NV | VK_SHADER_STAGE_INTERSECTION_BIT_NV;
  VkDescriptorSetLayoutBinding bindings[6];
  for (uint32_t b = 0; b < 6; ++b)
    bindings[b] = {b, b == 0 ? VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_NV : VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1,
                   stages, nullptr};
  VkDescriptorSetLayoutCreateInfo setInfo{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
  setInfo.bindingCount = 6;
  setInfo.pBindings = bindings;
  VkDescriptorSetLayout setLayout;
  if (!s.check(s.f.CreateDescriptorSetLayout(s.device(), &setInfo, nullptr, &setLayout),
               "vkCreateDescriptorSetLayout"))
    return false;
  s.cleanup.push_back([&s, setLayout] { s.f.DestroyDescriptorSetLayout(s.device(), setLayout, nullptr); });
  out.setLayout = setLayout;
  VkPipelineLayoutCreateInfo layoutInfo{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
  layoutInfo.setLayoutCount = 1;
  layoutInfo.pSetLayouts = &setLayout;
  VkPipelineLayout pipelineLayout;
  if (!s.check(s.f.CreatePipelineLayout(s.device(), &layoutInfo, nullptr, &pipelineLayout), "vkCreatePipelineLayout"))
    return false;
  s.cleanup.push_back([&s, pipelineLayout] { s.f.DestroyPipelineLayout(s.device(), pipelineLayout, nullptr); });
  out.pipelineLayout = pipelineLayout;
  return true;
}

// The ray-check pipeline; groups: 0 raygen, 1 miss, 2 triangles hit group, 3 procedural hit group.
bool createRayCheckPipeline(Session& s, VkPipelineLayout pipelineLayout, VkPipeline& out) {
  VkShaderModule rgen, rmiss, rchit, rint;
  if (!s.shader(kRayCheck_rgen, sizeof kRayCheck_rgen, rgen) || !s.shader(kRayCheck_rmiss, sizeof kRayCheck_rmiss, rmiss) ||
      !s.shader(kRayCheck_rchit, sizeof kRayCheck_rchit, rchit) || !s.shader(kRayCheck_rint, sizeof kRayCheck_rint, rint))
    return false;
  VkPipelineShaderStageCreateInfo shaderStages[4] = {};
  const VkShaderStageFlagBits stageBits[4] = {VK_SHADER_STAGE_RAYGEN_BIT_NV, VK_SHADER_STAGE_MISS_BIT_NV,
                                              VK_SHADER_STAGE_CLOSEST_HIT_BIT_NV, VK_SHADER_STAGE_INTERSECTION_BIT_NV};
  const VkShaderModule modules[4] = {rgen, rmiss, rchit, rint};
  for (int i = 0; i < 4; ++i) {
    shaderStages[i].sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
    shaderStages[i].stage = stageBits[i];
    shaderStages[i].module = modules[i];
    shaderStages[i].pName = "main";
  }
  VkRayTracingShaderGroupCreateInfoNV groups[4];
  for (auto& g : groups) {
    g = {VK_STRUCTURE_TYPE_RAY_TRACING_SHADER_GROUP_CREATE_INFO_NV};
    g.generalShader = g.closestHitShader = g.anyHitShader = g.intersectionShader = VK_SHADER_UNUSED_NV;
  }
  groups[0].type = VK_RAY_TRACING_SHADER_GROUP_TYPE_GENERAL_NV;
  groups[0].generalShader = 0;
  groups[1].type = VK_RAY_TRACING_SHADER_GROUP_TYPE_GENERAL_NV;
  groups[1].generalShader = 1;
  groups[2].type = VK_RAY_TRACING_SHADER_GROUP_TYPE_TRIANGLES_HIT_GROUP_NV;
  groups[2].closestHitShader = 2;
  groups[3].type = VK_RAY_TRACING_SHADER_GROUP_TYPE_PROCEDURAL_HIT_GROUP_NV;
  groups[3].closestHitShader = 2;
  groups[3].intersectionShader = 3;
  VkRayTracingPipelineCreateInfoNV pipelineInfo{VK_STRUCTURE_TYPE_RAY_TRACING_PIPELINE_CREATE_INFO_NV};
  pipelineInfo.stageCount = 4;
  pipelineInfo.pStages = shaderStages;
  pipelineInfo.groupCount = 4;
  pipelineInfo.pGroups = groups;
  pipelineInfo.maxRecursionDepth = 1;
  pipelineInfo.layout = pipelineLayout;
  pipelineInfo.basePipelineIndex = -1;
  VkPipeline pipeline;
  if (!s.check(s.f.CreateRayTracingPipelinesNV(s.device(), VK_NULL_HANDLE, 1, &pipelineInfo, nullptr, &pipeline),
               "vkCreateRayTracingPipelinesNV"))
    return false;
  s.cleanup.push_back([&s, pipeline] { s.f.DestroyPipeline(s.device(), pipeline, nullptr); });
  out = pipeline;
  return true;
}

// Shader binding table: raygen | miss | hit records (handle, then the record's index).
struct ShaderBindingTable {
  HostBuffer buffer;
  VkDeviceSize handleSize = 0;
  VkDeviceSize missOffset = 0;
  VkDeviceSize hitOffset = 0;
  VkDeviceSize hitStride = 0;
};

bool writeShaderBindingTable(Session& s, VkPipeline pipeline, const NvTraceScene& scene, ShaderBindingTable& out) {
  const auto& rt = s.context.rayTracingProperties;
  const uint32_t handleSize = rt.shaderGroupHandleSize;
  std::vector<uint8_t> handles(size_t(handleSize) * 4);
  if (!s.check(s.f.GetRayTracingShaderGroupHandlesNV(s.device(), pipeline, 0, 4, handles.size(), handles.data()),
               "vkGetRayTracingShaderGroupHandlesNV"))
    return false;
  const VkDeviceSize base = rt.shaderGroupBaseAlignment ? rt.shaderGroupBaseAlignment : 64;
  const VkDeviceSize hitStride = alignUp(handleSize + sizeof(uint32_t), handleSize);
  if (rt.maxShaderGroupStride && hitStride > rt.maxShaderGroupStride) {
    s.error = "hit record stride exceeds maxShaderGroupStride";
    return false;
  }
  const size_t recordCount = scene.recordIsProcedural.empty() ? 1 : scene.recordIsProcedural.size();
  out.handleSize = handleSize;
  out.missOffset = base;
  out.hitOffset = 2 * base;
  out.hitStride = hitStride;
  if (!s.hostBuffer(out.hitOffset + hitStride * recordCount, VK_BUFFER_USAGE_RAY_TRACING_BIT_NV, out.buffer))
    return false;
  auto* table = static_cast<uint8_t*>(out.buffer.mapped);
  std::memcpy(table, handles.data() + 0 * handleSize, handleSize);
  std::memcpy(table + out.missOffset, handles.data() + 1 * handleSize, handleSize);
  for (size_t r = 0; r < recordCount; ++r) {
    const bool procedural = r < scene.recordIsProcedural.size() && scene.recordIsProcedural[r];
    uint8_t* record = table + out.hitOffset + r * hitStride;
    std::memcpy(record, handles.data() + (procedural ? 3 : 2) * handleSize, handleSize);
    const uint32_t index = uint32_t(r);
    std::memcpy(record + handleSize, &index, sizeof index);
  }
  return true;
}

// The storage buffers of bindings 1..5, in binding order.
struct RayCheckBuffers {
  HostBuffer rays, hits, instances, geometries, boxes;
};

// Uploads the rays and the per-instance and per-geometry tables the hit shaders read.
bool uploadRayCheckBuffers(Session& s, const NvTraceScene& scene, const std::vector<NvTracedRay>& rays,
                           RayCheckBuffers& out) {
  std::vector<uint32_t> instanceInfo;
  for (const auto& i : scene.instances) {
    instanceInfo.push_back(i.sbtRecordOffset);
    instanceInfo.push_back(i.firstGeometrySlot);
  }
  std::vector<uint32_t> geometryTable;
  for (size_t g = 0; g < scene.geometryIsAabb.size(); ++g)
    geometryTable.push_back(scene.geometryIsAabb[g] && g < scene.geometryFirstBox.size() ? scene.geometryFirstBox[g]
                                                                                         : 0xFFFFFFFFu);
  const VkBufferUsageFlags storage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
  return s.upload(rays, storage, out.rays) && s.hostBuffer(rays.size() * sizeof(NvRayHit), storage, out.hits) &&
         s.upload(instanceInfo, storage, out.instances) && s.upload(geometryTable, storage, out.geometries) &&
         s.upload(scene.boxes, storage, out.boxes);
}

bool writeDescriptorSet(Session& s, VkDescriptorSetLayout setLayout, VkAccelerationStructureNV topLevel,
                        const RayCheckBuffers& buffers, VkDescriptorSet& out) {
  VkDescriptorPoolSize poolSizes[2] = {{VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_NV, 1},
                                       {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 5}};
  VkDescriptorPoolCreateInfo poolInfo{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
  poolInfo.maxSets = 1;
  poolInfo.poolSizeCount = 2;
  poolInfo.pPoolSizes = poolSizes;
  VkDescriptorPool pool;
  if (!s.check(s.f.CreateDescriptorPool(s.device(), &poolInfo, nullptr, &pool), "vkCreateDescriptorPool"))
    return false;
  s.cleanup.push_back([&s, pool] { s.f.DestroyDescriptorPool(s.device(), pool, nullptr); });
  VkDescriptorSetAllocateInfo setAllocate{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
  setAllocate.descriptorPool = pool;
  setAllocate.descriptorSetCount = 1;
  setAllocate.pSetLayouts = &setLayout;
  VkDescriptorSet set;
  if (!s.check(s.f.AllocateDescriptorSets(s.device(), &setAllocate, &set), "vkAllocateDescriptorSets")) return false;
  VkWriteDescriptorSetAccelerationStructureNV asWrite{VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET_ACCELERATION_STRUCTURE_NV};
  asWrite.accelerationStructureCount = 1;
  asWrite.pAccelerationStructures = &topLevel;
  const HostBuffer* storageBuffers[5] = {&buffers.rays, &buffers.hits, &buffers.instances, &buffers.geometries,
                                         &buffers.boxes};
  VkDescriptorBufferInfo bufferInfos[5];
  VkWriteDescriptorSet writes[6] = {};
  writes[0] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET, &asWrite, set, 0, 0, 1, VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_NV};
  for (uint32_t b = 0; b < 5; ++b) {
    bufferInfos[b] = {storageBuffers[b]->buffer, 0, VK_WHOLE_SIZE};
    writes[b + 1] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET, nullptr, set, b + 1, 0, 1,
                     VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, nullptr, &bufferInfos[b], nullptr};
  }
  s.f.UpdateDescriptorSets(s.device(), 6, writes, 0, nullptr);
  out = set;
  return true;
}

bool allocateCommandBuffer(Session& s, VkCommandBuffer& out) {
  VkCommandPoolCreateInfo commandPoolInfo{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  commandPoolInfo.flags = VK_COMMAND_POOL_CREATE_TRANSIENT_BIT;
  commandPoolInfo.queueFamilyIndex = s.context.queueFamilyIndex;
  VkCommandPool commandPool;
  if (!s.check(s.f.CreateCommandPool(s.device(), &commandPoolInfo, nullptr, &commandPool), "vkCreateCommandPool"))
    return false;
  s.cleanup.push_back([&s, commandPool] { s.f.DestroyCommandPool(s.device(), commandPool, nullptr); });
  VkCommandBufferAllocateInfo cbInfo{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
  cbInfo.commandPool = commandPool;
  cbInfo.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  cbInfo.commandBufferCount = 1;
  if (!s.check(s.f.AllocateCommandBuffers(s.device(), &cbInfo, &out), "vkAllocateCommandBuffers")) return false;
  if (s.context.setCommandBufferDispatch) *reinterpret_cast<void**>(out) = *reinterpret_cast<void**>(s.device());
  return true;
}

bool recordTraceRays(Session& s, VkCommandBuffer cb, VkPipeline pipeline, VkPipelineLayout pipelineLayout,
                     VkDescriptorSet set, const ShaderBindingTable& sbt, uint32_t rayCount) {
  auto& f = s.f;
  VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  if (!s.check(f.BeginCommandBuffer(cb, &begin), "vkBeginCommandBuffer")) return false;
  // Every earlier command of the queue (the builds) completes before the rays are traced.
  const VkMemoryBarrier before{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_MEMORY_WRITE_BIT,
                               VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_NV | VK_ACCESS_SHADER_READ_BIT |
                                   VK_ACCESS_SHADER_WRITE_BIT};
  f.CmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, VK_PIPELINE_STAGE_RAY_TRACING_SHADER_BIT_NV, 0, 1,
                       &before, 0, nullptr, 0, nullptr);
  f.CmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_RAY_TRACING_NV, pipeline);
  f.CmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_RAY_TRACING_NV, pipelineLayout, 0, 1, &set, 0, nullptr);
  const VkBuffer table = sbt.buffer.buffer;
  f.CmdTraceRaysNV(cb, table, 0, table, sbt.missOffset, sbt.handleSize, table, sbt.hitOffset, sbt.hitStride,
                   VK_NULL_HANDLE, 0, 0, rayCount, 1, 1);
  const VkMemoryBarrier after{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_SHADER_WRITE_BIT,
                              VK_ACCESS_HOST_READ_BIT};
  f.CmdPipelineBarrier(cb, VK_PIPELINE_STAGE_RAY_TRACING_SHADER_BIT_NV, VK_PIPELINE_STAGE_HOST_BIT, 0, 1, &after, 0,
                       nullptr, 0, nullptr);
  return s.check(f.EndCommandBuffer(cb), "vkEndCommandBuffer");
}

bool submitAndWait(Session& s, VkCommandBuffer cb) {
  VkFenceCreateInfo fenceInfo{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
  VkFence fence;
  if (!s.check(s.f.CreateFence(s.device(), &fenceInfo, nullptr, &fence), "vkCreateFence")) return false;
  s.cleanup.push_back([&s, fence] { s.f.DestroyFence(s.device(), fence, nullptr); });
  VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
  submit.commandBufferCount = 1;
  submit.pCommandBuffers = &cb;
  if (!s.check(s.f.QueueSubmit(s.context.queue, 1, &submit, fence), "vkQueueSubmit")) return false;
  if (!s.check(s.f.WaitForFences(s.device(), 1, &fence, VK_TRUE, 10'000'000'000ull), "vkWaitForFences")) {
    // The queue still owns our objects: leaking them beats freeing what the GPU may use.
    s.cleanup.clear();
    return false;
  }
  return true;
}

}  // namespace

bool traceRaysNV(const NvRayTracerContext& context, VkAccelerationStructureNV topLevel, const NvTraceScene& scene,
                 const std::vector<NvTracedRay>& rays, std::vector<NvRayHit>& hits, std::string& error) {
  hits.clear();
  if (rays.empty()) return true;
  Session s(context);
  auto fail = [&] {
    error = s.error;
    return false;
  };
  if (!s.load()) return fail();
  if (context.rayTracingProperties.shaderGroupHandleSize == 0) {
    s.error = "VkPhysicalDeviceRayTracingPropertiesNV.shaderGroupHandleSize is 0";
    return fail();
  }
  RayCheckLayout layout;
  VkPipeline pipeline;
  ShaderBindingTable sbt;
  RayCheckBuffers buffers;
  VkDescriptorSet set;
  VkCommandBuffer cb;
  if (!createRayCheckLayout(s, layout) || !createRayCheckPipeline(s, layout.pipelineLayout, pipeline) ||
      !writeShaderBindingTable(s, pipeline, scene, sbt) || !uploadRayCheckBuffers(s, scene, rays, buffers) ||
      !writeDescriptorSet(s, layout.setLayout, topLevel, buffers, set) || !allocateCommandBuffer(s, cb) ||
      !recordTraceRays(s, cb, pipeline, layout.pipelineLayout, set, sbt, uint32_t(rays.size())) ||
      !submitAndWait(s, cb))
    return fail();
  hits.resize(rays.size());
  std::memcpy(hits.data(), buffers.hits.mapped, rays.size() * sizeof(NvRayHit));
  return true;
}

}  // namespace clastrace::capture
