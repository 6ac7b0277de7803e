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
  const VkDevice device = context.device;
  auto& f = s.f;
  const auto& rt = context.rayTracingProperties;
  if (rt.shaderGroupHandleSize == 0) {
    s.error = "VkPhysicalDeviceRayTracingPropertiesNV.shaderGroupHandleSize is 0";
    return fail();
  }

  // Descriptor set: top level, rays, hits, instance table, geometry table, boxes.
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
  if (!s.check(f.CreateDescriptorSetLayout(device, &setInfo, nullptr, &setLayout), "vkCreateDescriptorSetLayout"))
    return fail();
  s.cleanup.push_back([&s, setLayout] { s.f.DestroyDescriptorSetLayout(s.device(), setLayout, nullptr); });
  VkPipelineLayoutCreateInfo layoutInfo{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
  layoutInfo.setLayoutCount = 1;
  layoutInfo.pSetLayouts = &setLayout;
  VkPipelineLayout pipelineLayout;
  if (!s.check(f.CreatePipelineLayout(device, &layoutInfo, nullptr, &pipelineLayout), "vkCreatePipelineLayout"))
    return fail();
  s.cleanup.push_back([&s, pipelineLayout] { s.f.DestroyPipelineLayout(s.device(), pipelineLayout, nullptr); });

  VkShaderModule rgen, rmiss, rchit, rint;
  if (!s.shader(kRayCheck_rgen, sizeof kRayCheck_rgen, rgen) || !s.shader(kRayCheck_rmiss, sizeof kRayCheck_rmiss, rmiss) ||
      !s.shader(kRayCheck_rchit, sizeof kRayCheck_rchit, rchit) || !s.shader(kRayCheck_rint, sizeof kRayCheck_rint, rint))
    return fail();
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
  // Groups: 0 raygen, 1 miss, 2 triangles hit group, 3 procedural hit group.
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
  if (!s.check(f.CreateRayTracingPipelinesNV(device, VK_NULL_HANDLE, 1, &pipelineInfo, nullptr, &pipeline),
               "vkCreateRayTracingPipelinesNV"))
    return fail();
  s.cleanup.push_back([&s, pipeline] { s.f.DestroyPipeline(s.device(), pipeline, nullptr); });

  const uint32_t handleSize = rt.shaderGroupHandleSize;
  std::vector<uint8_t> handles(size_t(handleSize) * 4);
  if (!s.check(f.GetRayTracingShaderGroupHandlesNV(device, pipeline, 0, 4, handles.size(), handles.data()),
               "vkGetRayTracingShaderGroupHandlesNV"))
    return fail();

  // Shader binding table: raygen | miss | hit records (handle, then the record's index).
  const VkDeviceSize base = rt.shaderGroupBaseAlignment ? rt.shaderGroupBaseAlignment : 64;
  const VkDeviceSize hitStride = alignUp(handleSize + sizeof(uint32_t), handleSize);
  if (rt.maxShaderGroupStride && hitStride > rt.maxShaderGroupStride) {
    s.error = "hit record stride exceeds maxShaderGroupStride";
    return fail();
  }
  const size_t recordCount = scene.recordIsProcedural.empty() ? 1 : scene.recordIsProcedural.size();
  const VkDeviceSize missOffset = base;
  const VkDeviceSize hitOffset = 2 * base;
  HostBuffer sbt;
  if (!s.hostBuffer(hitOffset + hitStride * recordCount, VK_BUFFER_USAGE_RAY_TRACING_BIT_NV, sbt)) return fail();
  auto* table = static_cast<uint8_t*>(sbt.mapped);
  std::memcpy(table, handles.data() + 0 * handleSize, handleSize);
  std::memcpy(table + missOffset, handles.data() + 1 * handleSize, handleSize);
  for (size_t r = 0; r < recordCount; ++r) {
    const bool procedural = r < scene.recordIsProcedural.size() && scene.recordIsProcedural[r];
    uint8_t* record = table + hitOffset + r * hitStride;
    std::memcpy(record, handles.data() + (procedural ? 3 : 2) * handleSize, handleSize);
    const uint32_t index = uint32_t(r);
    std::memcpy(record + handleSize, &index, sizeof index);
  }

  // Per-instance and per-geometry tables the hit shaders read.
  std::vector<uint32_t> instanceInfo;
  for (const auto& i : scene.instances) {
    instanceInfo.push_back(i.sbtRecordOffset);
    instanceInfo.push_back(i.firstGeometrySlot);
  }
  std::vector<uint32_t> geometryTable;
  for (size_t g = 0; g < scene.geometryIsAabb.size(); ++g)
    geometryTable.push_back(scene.geometryIsAabb[g] && g < scene.geometryFirstBox.size() ? scene.geometryFirstBox[g]
                                                                                         : 0xFFFFFFFFu);
  HostBuffer rayBuffer, hitBuffer, instanceBuffer, geometryBuffer, boxBuffer;
  const VkBufferUsageFlags storage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
  if (!s.upload(rays, storage, rayBuffer) || !s.hostBuffer(rays.size() * sizeof(NvRayHit), storage, hitBuffer) ||
      !s.upload(instanceInfo, storage, instanceBuffer) || !s.upload(geometryTable, storage, geometryBuffer) ||
      !s.upload(scene.boxes, storage, boxBuffer))
    return fail();

  VkDescriptorPoolSize poolSizes[2] = {{VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_NV, 1},
                                       {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 5}};
  VkDescriptorPoolCreateInfo poolInfo{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
  poolInfo.maxSets = 1;
  poolInfo.poolSizeCount = 2;
  poolInfo.pPoolSizes = poolSizes;
  VkDescriptorPool pool;
  if (!s.check(f.CreateDescriptorPool(device, &poolInfo, nullptr, &pool), "vkCreateDescriptorPool")) return fail();
  s.cleanup.push_back([&s, pool] { s.f.DestroyDescriptorPool(s.device(), pool, nullptr); });
  VkDescriptorSetAllocateInfo setAllocate{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
  setAllocate.descriptorPool = pool;
  setAllocate.descriptorSetCount = 1;
  setAllocate.pSetLayouts = &setLayout;
  VkDescriptorSet set;
  if (!s.check(f.AllocateDescriptorSets(device, &setAllocate, &set), "vkAllocateDescriptorSets")) return fail();
  VkWriteDescriptorSetAccelerationStructureNV asWrite{VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET_ACCELERATION_STRUCTURE_NV};
  asWrite.accelerationStructureCount = 1;
  asWrite.pAccelerationStructures = &topLevel;
  const HostBuffer* storageBuffers[5] = {&rayBuffer, &hitBuffer, &instanceBuffer, &geometryBuffer, &boxBuffer};
  VkDescriptorBufferInfo bufferInfos[5];
  VkWriteDescriptorSet writes[6] = {};
  writes[0] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET, &asWrite, set, 0, 0, 1, VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_NV};
  for (uint32_t b = 0; b < 5; ++b) {
    bufferInfos[b] = {storageBuffers[b]->buffer, 0, VK_WHOLE_SIZE};
    writes[b + 1] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET, nullptr, set, b + 1, 0, 1,
                     VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, nullptr, &bufferInfos[b], nullptr};
  }
  f.UpdateDescriptorSets(device, 6, writes, 0, nullptr);

  VkCommandPoolCreateInfo commandPoolInfo{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  commandPoolInfo.flags = VK_COMMAND_POOL_CREATE_TRANSIENT_BIT;
  commandPoolInfo.queueFamilyIndex = context.queueFamilyIndex;
  VkCommandPool commandPool;
  if (!s.check(f.CreateCommandPool(device, &commandPoolInfo, nullptr, &commandPool), "vkCreateCommandPool"))
    return fail();
  s.cleanup.push_back([&s, commandPool] { s.f.DestroyCommandPool(s.device(), commandPool, nullptr); });
  VkCommandBufferAllocateInfo cbInfo{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
  cbInfo.commandPool = commandPool;
  cbInfo.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  cbInfo.commandBufferCount = 1;
  VkCommandBuffer cb;
  if (!s.check(f.AllocateCommandBuffers(device, &cbInfo, &cb), "vkAllocateCommandBuffers")) return fail();
  if (context.setCommandBufferDispatch) *reinterpret_cast<void**>(cb) = *reinterpret_cast<void**>(device);

  VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  if (!s.check(f.BeginCommandBuffer(cb, &begin), "vkBeginCommandBuffer")) return fail();
  // Every earlier command of the queue (the builds) completes before the rays are traced.
  const VkMemoryBarrier before{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_MEMORY_WRITE_BIT,
                               VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_NV | VK_ACCESS_SHADER_READ_BIT |
                                   VK_ACCESS_SHADER_WRITE_BIT};
  f.CmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, VK_PIPELINE_STAGE_RAY_TRACING_SHADER_BIT_NV, 0, 1,
                       &before, 0, nullptr, 0, nullptr);
  f.CmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_RAY_TRACING_NV, pipeline);
  f.CmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_RAY_TRACING_NV, pipelineLayout, 0, 1, &set, 0, nullptr);
  f.CmdTraceRaysNV(cb, sbt.buffer, 0, sbt.buffer, missOffset, handleSize, sbt.buffer, hitOffset, hitStride,
                   VK_NULL_HANDLE, 0, 0, uint32_t(rays.size()), 1, 1);
  const VkMemoryBarrier after{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_SHADER_WRITE_BIT,
                              VK_ACCESS_HOST_READ_BIT};
  f.CmdPipelineBarrier(cb, VK_PIPELINE_STAGE_RAY_TRACING_SHADER_BIT_NV, VK_PIPELINE_STAGE_HOST_BIT, 0, 1, &after, 0,
                       nullptr, 0, nullptr);
  if (!s.check(f.EndCommandBuffer(cb), "vkEndCommandBuffer")) return fail();

  VkFenceCreateInfo fenceInfo{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
  VkFence fence;
  if (!s.check(f.CreateFence(device, &fenceInfo, nullptr, &fence), "vkCreateFence")) return fail();
  s.cleanup.push_back([&s, fence] { s.f.DestroyFence(s.device(), fence, nullptr); });
  VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
  submit.commandBufferCount = 1;
  submit.pCommandBuffers = &cb;
  if (!s.check(f.QueueSubmit(context.queue, 1, &submit, fence), "vkQueueSubmit")) return fail();
  if (!s.check(f.WaitForFences(device, 1, &fence, VK_TRUE, 10'000'000'000ull), "vkWaitForFences")) {
    // The queue still owns our objects: leaking them beats freeing what the GPU may use.
    s.cleanup.clear();
    return fail();
  }
  hits.resize(rays.size());
  std::memcpy(hits.data(), hitBuffer.mapped, rays.size() * sizeof(NvRayHit));
  return true;
}

}  // namespace clastrace::capture
