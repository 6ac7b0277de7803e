// SPDX-License-Identifier: Apache-2.0
// A headless program for the capture test of the commands that read acceleration structures
// (capture/src/consumer_commands.cpp), on lavapipe 25 (VK_KHR_acceleration_structure, ray
// query, ray-tracing pipelines). It builds a one-triangle BLAS and a TLAS over it, then in one
// command buffer: a compute dispatch with a ray query against the TLAS bound in a descriptor set
// (the TLAS address also in the push constants), the same through a set written with an update
// template and through pushed descriptors, a plain dispatch, a draw whose vertex shader runs the
// same ray query, vkCmdTraceRaysKHR (4x2x1)
// and, when the device has rayTracingPipelineTraceRaysIndirect, vkCmdTraceRaysIndirectKHR with
// the same dimensions. After the fence it checks what the shaders wrote.
// With "sources": only a dispatch bound and pushed with VK_KHR_maintenance6's
// vkCmdBindDescriptorSets2KHR / vkCmdPushConstants2KHR, and one whose UPDATE_AFTER_BIND set is
// rewritten between recording and submission, and one pushed with vkCmdPushDescriptorSet2KHR.
// With "descriptor-buffer": one ray-query dispatch whose set comes from a descriptor buffer
// (VK_EXT_descriptor_buffer), the TLAS descriptor written there with vkGetDescriptorEXT.
// With "address-in-buffer": ray-query dispatches whose shader reads the TLAS address from a
// storage buffer (accelerationStructureEXT(uint64_t)): one through a bound set, one through pushed
// descriptors whose buffer gets the address only after recording, and one whose buffer holds a
// value that is no structure's address (that shader does not trace), and one reading it from a
// uniform buffer bound with a dynamic offset.
// Usage: ray_consumers_app OUT.json [sources|descriptor-buffer|address-in-buffer]. OUT.json
// names the handles and addresses the capture must report. Exit 0 and "ok" when every result is right; 2 otherwise.
#include <clastrace/vk_maintenance6_abi.h>
#include <vulkan/vulkan.h>

#include <cstdarg>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

// The shaders' SPIR-V as uint32_t arrays, compiled at build time (tests/apps/CMakeLists.txt).
#include "address_in_buffer_comp.h"   // kAddressInBufferComp
#include "address_in_uniform_comp.h"  // kAddressInUniformComp
#include "plain_comp.h"               // kPlainComp
#include "ray_query_comp.h"           // kRayQueryComp
#include "ray_query_vert.h"           // kRayQueryVert
#include "rays_rchit.h"               // kRaysRchit
#include "rays_rgen.h"                // kRaysRgen
#include "rays_rmiss.h"               // kRaysRmiss

namespace {

void check(VkResult result, const char* call) {
    if (result == VK_SUCCESS) return;
    std::fprintf(stderr, "ray_consumers_app: %s failed: %d\n", call, int(result));
    std::exit(2);
}
#define CHECK(call) check((call), #call)

void fail(const char* why) {
    std::fprintf(stderr, "ray_consumers_app: %s\n", why);
    std::exit(2);
}

VkDeviceSize align_up(VkDeviceSize value, VkDeviceSize alignment) {
    return (value + alignment - 1) / alignment * alignment;
}

struct Functions {
    PFN_vkGetAccelerationStructureBuildSizesKHR build_sizes;
    PFN_vkCreateAccelerationStructureKHR create_structure;
    PFN_vkGetAccelerationStructureDeviceAddressKHR structure_address;
    PFN_vkCmdBuildAccelerationStructuresKHR build;
    PFN_vkCreateRayTracingPipelinesKHR create_ray_tracing_pipelines;
    PFN_vkGetRayTracingShaderGroupHandlesKHR group_handles;
    PFN_vkCmdTraceRaysKHR trace_rays;
    PFN_vkCmdTraceRaysIndirectKHR trace_rays_indirect;
    PFN_vkCmdPushDescriptorSetKHR push_descriptor_set;
    PFN_vkCmdBindDescriptorSets2KHR bind_descriptor_sets2;
    PFN_vkCmdPushConstants2KHR push_constants2;
    PFN_vkCmdPushDescriptorSet2KHR push_descriptor_set2;
    // VK_EXT_descriptor_buffer ("descriptor-buffer" mode only).
    PFN_vkGetDescriptorSetLayoutSizeEXT set_layout_size;
    PFN_vkGetDescriptorSetLayoutBindingOffsetEXT binding_offset;
    PFN_vkGetDescriptorEXT get_descriptor;
    PFN_vkCmdBindDescriptorBuffersEXT bind_descriptor_buffers;
    PFN_vkCmdSetDescriptorBufferOffsetsEXT set_descriptor_buffer_offsets;
};

struct Device {
    VkInstance instance = VK_NULL_HANDLE;
    VkPhysicalDevice physical = VK_NULL_HANDLE;
    VkDevice device = VK_NULL_HANDLE;
    VkQueue queue = VK_NULL_HANDLE;
    uint32_t family = 0;
    bool trace_rays_indirect = false;
    bool descriptor_buffer = false;  // VK_EXT_descriptor_buffer enabled
    VkPhysicalDeviceDescriptorBufferPropertiesEXT descriptor_buffer_properties{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_DESCRIPTOR_BUFFER_PROPERTIES_EXT};
    VkPhysicalDeviceRayTracingPipelinePropertiesKHR rt{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_RAY_TRACING_PIPELINE_PROPERTIES_KHR};
    VkPhysicalDeviceAccelerationStructurePropertiesKHR as{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ACCELERATION_STRUCTURE_PROPERTIES_KHR};
    Functions fn{};
};

template <typename T>
T device_function(VkDevice device, const char* name) {
    auto f = reinterpret_cast<T>(vkGetDeviceProcAddr(device, name));
    if (!f) fail(name);
    return f;
}

void load_functions(Device& d) {
    d.fn.build_sizes = device_function<PFN_vkGetAccelerationStructureBuildSizesKHR>(
        d.device, "vkGetAccelerationStructureBuildSizesKHR");
    d.fn.create_structure =
        device_function<PFN_vkCreateAccelerationStructureKHR>(d.device,
                                                              "vkCreateAccelerationStructureKHR");
    d.fn.structure_address = device_function<PFN_vkGetAccelerationStructureDeviceAddressKHR>(
        d.device, "vkGetAccelerationStructureDeviceAddressKHR");
    d.fn.build = device_function<PFN_vkCmdBuildAccelerationStructuresKHR>(
        d.device, "vkCmdBuildAccelerationStructuresKHR");
    d.fn.create_ray_tracing_pipelines =
        device_function<PFN_vkCreateRayTracingPipelinesKHR>(d.device,
                                                            "vkCreateRayTracingPipelinesKHR");
    d.fn.group_handles = device_function<PFN_vkGetRayTracingShaderGroupHandlesKHR>(
        d.device, "vkGetRayTracingShaderGroupHandlesKHR");
    d.fn.trace_rays = device_function<PFN_vkCmdTraceRaysKHR>(d.device, "vkCmdTraceRaysKHR");
    d.fn.trace_rays_indirect =
        device_function<PFN_vkCmdTraceRaysIndirectKHR>(d.device, "vkCmdTraceRaysIndirectKHR");
    d.fn.push_descriptor_set =
        device_function<PFN_vkCmdPushDescriptorSetKHR>(d.device, "vkCmdPushDescriptorSetKHR");
    d.fn.bind_descriptor_sets2 =
        device_function<PFN_vkCmdBindDescriptorSets2KHR>(d.device, "vkCmdBindDescriptorSets2KHR");
    d.fn.push_constants2 =
        device_function<PFN_vkCmdPushConstants2KHR>(d.device, "vkCmdPushConstants2KHR");
    d.fn.push_descriptor_set2 =
        device_function<PFN_vkCmdPushDescriptorSet2KHR>(d.device, "vkCmdPushDescriptorSet2KHR");
    if (!d.descriptor_buffer) return;
    d.fn.set_layout_size =
        device_function<PFN_vkGetDescriptorSetLayoutSizeEXT>(d.device,
                                                             "vkGetDescriptorSetLayoutSizeEXT");
    d.fn.binding_offset = device_function<PFN_vkGetDescriptorSetLayoutBindingOffsetEXT>(
        d.device, "vkGetDescriptorSetLayoutBindingOffsetEXT");
    d.fn.get_descriptor = device_function<PFN_vkGetDescriptorEXT>(d.device, "vkGetDescriptorEXT");
    d.fn.bind_descriptor_buffers =
        device_function<PFN_vkCmdBindDescriptorBuffersEXT>(d.device,
                                                           "vkCmdBindDescriptorBuffersEXT");
    d.fn.set_descriptor_buffer_offsets = device_function<PFN_vkCmdSetDescriptorBufferOffsetsEXT>(
        d.device, "vkCmdSetDescriptorBufferOffsetsEXT");
}

Device create_device(bool descriptor_buffer = false) {
    Device d;
    d.descriptor_buffer = descriptor_buffer;
    VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
    app.pApplicationName = "ray_consumers_app";
    app.apiVersion = VK_API_VERSION_1_3;
    VkInstanceCreateInfo instance_info{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
    instance_info.pApplicationInfo = &app;
    CHECK(vkCreateInstance(&instance_info, nullptr, &d.instance));
    uint32_t count = 1;
    VkResult listed = vkEnumeratePhysicalDevices(d.instance, &count, &d.physical);
    if ((listed != VK_SUCCESS && listed != VK_INCOMPLETE) || count == 0) fail("no Vulkan device");
    d.rt.pNext = &d.as;
    d.as.pNext = &d.descriptor_buffer_properties;
    VkPhysicalDeviceProperties2 properties{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &d.rt};
    vkGetPhysicalDeviceProperties2(d.physical, &properties);

    VkPhysicalDeviceRayTracingPipelineFeaturesKHR rt_features{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_RAY_TRACING_PIPELINE_FEATURES_KHR};
    VkPhysicalDeviceFeatures2 supported{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &rt_features};
    vkGetPhysicalDeviceFeatures2(d.physical, &supported);
    if (!rt_features.rayTracingPipeline) fail("no rayTracingPipeline");
    d.trace_rays_indirect = rt_features.rayTracingPipelineTraceRaysIndirect == VK_TRUE;

    const float priority = 1.0f;
    VkDeviceQueueCreateInfo queue_info{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
    queue_info.queueFamilyIndex = d.family;  // lavapipe: one family, every kind of work
    queue_info.queueCount = 1;
    queue_info.pQueuePriorities = &priority;
    VkPhysicalDeviceRayQueryFeaturesKHR ray_query{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_RAY_QUERY_FEATURES_KHR};
    ray_query.rayQuery = VK_TRUE;
    VkPhysicalDeviceRayTracingPipelineFeaturesKHR pipeline{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_RAY_TRACING_PIPELINE_FEATURES_KHR, &ray_query};
    pipeline.rayTracingPipeline = VK_TRUE;
    pipeline.rayTracingPipelineTraceRaysIndirect = d.trace_rays_indirect;
    VkPhysicalDeviceAccelerationStructureFeaturesKHR structures{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ACCELERATION_STRUCTURE_FEATURES_KHR, &pipeline};
    structures.accelerationStructure = VK_TRUE;
    structures.descriptorBindingAccelerationStructureUpdateAfterBind = VK_TRUE;
    VkPhysicalDeviceVulkan12Features v12{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES,
                                         &structures};
    v12.bufferDeviceAddress = VK_TRUE;
    VkPhysicalDeviceVulkan13Features v13{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_3_FEATURES};
    v13.dynamicRendering = VK_TRUE;
    structures.pNext = &v13;
    VkPhysicalDeviceMaintenance6FeaturesKHR maintenance6{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_MAINTENANCE_6_FEATURES_KHR, &pipeline};
    maintenance6.maintenance6 = VK_TRUE;
    v13.pNext = &maintenance6;
    VkPhysicalDeviceDescriptorBufferFeaturesEXT descriptor_buffers{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_DESCRIPTOR_BUFFER_FEATURES_EXT, &pipeline};
    descriptor_buffers.descriptorBuffer = VK_TRUE;
    if (descriptor_buffer) maintenance6.pNext = &descriptor_buffers;
    VkPhysicalDeviceFeatures2 features{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &v12};
    features.features.vertexPipelineStoresAndAtomics = VK_TRUE;
    features.features.shaderInt64 = VK_TRUE;  // address_in_buffer.comp's uint64_t
    const char* extensions[] = {"VK_KHR_acceleration_structure",
                                "VK_KHR_ray_query",
                                "VK_KHR_ray_tracing_pipeline",
                                "VK_KHR_deferred_host_operations",
                                "VK_KHR_push_descriptor",
                                VK_KHR_MAINTENANCE_6_EXTENSION_NAME,
                                VK_EXT_DESCRIPTOR_BUFFER_EXTENSION_NAME};
    VkDeviceCreateInfo device_info{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO, &features};
    device_info.queueCreateInfoCount = 1;
    device_info.pQueueCreateInfos = &queue_info;
    device_info.enabledExtensionCount = descriptor_buffer ? 7 : 6;
    device_info.ppEnabledExtensionNames = extensions;
    CHECK(vkCreateDevice(d.physical, &device_info, nullptr, &d.device));
    vkGetDeviceQueue(d.device, d.family, 0, &d.queue);
    load_functions(d);
    return d;
}

// A host-visible buffer with a device address (every buffer here is one).
struct Buffer {
    VkBuffer buffer = VK_NULL_HANDLE;
    VkDeviceMemory memory = VK_NULL_HANDLE;
    VkDeviceAddress address = 0;
    void* mapped = nullptr;
};

Buffer create_buffer(const Device& d, VkDeviceSize size, VkBufferUsageFlags usage) {
    Buffer b;
    VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
    info.size = size;
    info.usage = usage | VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
    CHECK(vkCreateBuffer(d.device, &info, nullptr, &b.buffer));
    VkMemoryRequirements requirements;
    vkGetBufferMemoryRequirements(d.device, b.buffer, &requirements);
    VkPhysicalDeviceMemoryProperties memory;
    vkGetPhysicalDeviceMemoryProperties(d.physical, &memory);
    const VkMemoryPropertyFlags wanted =
        VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
    uint32_t type = 0;
    while (type < memory.memoryTypeCount &&
           (!(requirements.memoryTypeBits & (1u << type)) ||
            (memory.memoryTypes[type].propertyFlags & wanted) != wanted))
        ++type;
    if (type == memory.memoryTypeCount) fail("no host-visible memory type");
    VkMemoryAllocateFlagsInfo flags{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_FLAGS_INFO};
    flags.flags = VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT;
    VkMemoryAllocateInfo allocate{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, &flags};
    allocate.allocationSize = requirements.size;
    allocate.memoryTypeIndex = type;
    CHECK(vkAllocateMemory(d.device, &allocate, nullptr, &b.memory));
    CHECK(vkBindBufferMemory(d.device, b.buffer, b.memory, 0));
    CHECK(vkMapMemory(d.device, b.memory, 0, VK_WHOLE_SIZE, 0, &b.mapped));
    std::memset(b.mapped, 0, size);
    VkBufferDeviceAddressInfo address{VK_STRUCTURE_TYPE_BUFFER_DEVICE_ADDRESS_INFO};
    address.buffer = b.buffer;
    b.address = vkGetBufferDeviceAddress(d.device, &address);
    return b;
}

struct Structure {
    VkAccelerationStructureKHR handle = VK_NULL_HANDLE;
    VkDeviceAddress address = 0;
    Buffer storage, scratch;
};

// Creates a structure for `geometry` (one primitive range of `primitives`) and records its
// build into `cb`.
Structure build_structure(const Device& d, VkCommandBuffer cb, VkAccelerationStructureTypeKHR type,
                          const VkAccelerationStructureGeometryKHR& geometry, uint32_t primitives) {
    VkAccelerationStructureBuildGeometryInfoKHR info{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR};
    info.type = type;
    info.mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR;
    info.geometryCount = 1;
    info.pGeometries = &geometry;
    VkAccelerationStructureBuildSizesInfoKHR sizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
    d.fn.build_sizes(d.device, VK_ACCELERATION_STRUCTURE_BUILD_TYPE_DEVICE_KHR, &info, &primitives,
                     &sizes);
    Structure s;
    s.storage = create_buffer(d, sizes.accelerationStructureSize,
                              VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR);
    const VkDeviceSize scratch_alignment = d.as.minAccelerationStructureScratchOffsetAlignment;
    s.scratch = create_buffer(d, sizes.buildScratchSize + scratch_alignment,
                              VK_BUFFER_USAGE_STORAGE_BUFFER_BIT);
    VkAccelerationStructureCreateInfoKHR create{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_CREATE_INFO_KHR};
    create.buffer = s.storage.buffer;
    create.size = sizes.accelerationStructureSize;
    create.type = type;
    CHECK(d.fn.create_structure(d.device, &create, nullptr, &s.handle));
    VkAccelerationStructureDeviceAddressInfoKHR address{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_DEVICE_ADDRESS_INFO_KHR};
    address.accelerationStructure = s.handle;
    s.address = d.fn.structure_address(d.device, &address);
    info.dstAccelerationStructure = s.handle;
    info.scratchData.deviceAddress = align_up(s.scratch.address, scratch_alignment);
    VkAccelerationStructureBuildRangeInfoKHR range{primitives, 0, 0, 0};
    const VkAccelerationStructureBuildRangeInfoKHR* ranges = &range;
    d.fn.build(cb, 1, &info, &ranges);
    VkMemoryBarrier built{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
    built.srcAccessMask = VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
    built.dstAccessMask = VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR;
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                         VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR |
                             VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT |
                             VK_PIPELINE_STAGE_RAY_TRACING_SHADER_BIT_KHR,
                         0, 1, &built, 0, nullptr, 0, nullptr);
    return s;
}

struct Scene {
    Buffer vertices, instances;
    Structure bottom, top;
};

// The triangle (0,0,0) (1,0,0) (0,1,0) in a BLAS, one identity instance of it in a TLAS.
Scene build_scene(const Device& d, VkCommandBuffer cb) {
    Scene s;
    const VkBufferUsageFlags input =
        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    s.vertices = create_buffer(d, 9 * sizeof(float), input);
    const float triangle[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    std::memcpy(s.vertices.mapped, triangle, sizeof triangle);
    VkAccelerationStructureGeometryKHR geometry{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    geometry.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    geometry.flags = VK_GEOMETRY_OPAQUE_BIT_KHR;
    auto& triangles = geometry.geometry.triangles;
    triangles.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_TRIANGLES_DATA_KHR;
    triangles.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    triangles.vertexData.deviceAddress = s.vertices.address;
    triangles.vertexStride = 3 * sizeof(float);
    triangles.maxVertex = 2;
    triangles.indexType = VK_INDEX_TYPE_NONE_KHR;
    s.bottom = build_structure(d, cb, VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, geometry, 1);

    s.instances = create_buffer(d, sizeof(VkAccelerationStructureInstanceKHR), input);
    VkAccelerationStructureInstanceKHR instance{};
    instance.transform.matrix[0][0] = instance.transform.matrix[1][1] =
        instance.transform.matrix[2][2] = 1.0f;
    instance.mask = 0xFF;
    instance.flags = VK_GEOMETRY_INSTANCE_TRIANGLE_FACING_CULL_DISABLE_BIT_KHR;
    instance.accelerationStructureReference = s.bottom.address;
    std::memcpy(s.instances.mapped, &instance, sizeof instance);
    VkAccelerationStructureGeometryKHR instances{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    instances.geometryType = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    instances.geometry.instances.sType =
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_INSTANCES_DATA_KHR;
    instances.geometry.instances.data.deviceAddress = s.instances.address;
    s.top = build_structure(d, cb, VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR, instances, 1);
    return s;
}

VkShaderModule shader(const Device& d, const uint32_t* code, size_t size) {
    VkShaderModuleCreateInfo info{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
    info.codeSize = size;
    info.pCode = code;
    VkShaderModule module;
    CHECK(vkCreateShaderModule(d.device, &info, nullptr, &module));
    return module;
}

// Push constants: the TLAS address (the capture's source 3) and the first result slot.
struct Constants {
    VkDeviceAddress scene_address;
    uint32_t first;
    uint32_t unused;
};

struct Pipelines {
    VkDescriptorSetLayout set_layout = VK_NULL_HANDLE;
    VkPipelineLayout layout = VK_NULL_HANDLE;
    VkDescriptorSet set = VK_NULL_HANDLE;
    VkDescriptorSet template_set = VK_NULL_HANDLE;  // written with an update template
    VkPipelineLayout push_layout = VK_NULL_HANDLE;  // set 0 pushed (vkCmdPushDescriptorSetKHR)
    VkPipeline ray_query = VK_NULL_HANDLE, plain = VK_NULL_HANDLE, rays = VK_NULL_HANDLE;
    VkPipeline pushed_ray_query = VK_NULL_HANDLE;  // the ray query over pushed descriptors
    VkPipeline draw_ray_query = VK_NULL_HANDLE;    // a vertex shader's ray query
};

constexpr VkShaderStageFlags kStages =
    VK_SHADER_STAGE_COMPUTE_BIT | VK_SHADER_STAGE_RAYGEN_BIT_KHR | VK_SHADER_STAGE_VERTEX_BIT;

// One set, and the push constants of every shader here.
VkPipelineLayout pipeline_layout_of(const Device& d, VkDescriptorSetLayout set_layout) {
    VkPushConstantRange range{kStages, 0, sizeof(Constants)};
    VkPipelineLayoutCreateInfo info{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
    info.setLayoutCount = 1;
    info.pSetLayouts = &set_layout;
    info.pushConstantRangeCount = 1;
    info.pPushConstantRanges = &range;
    VkPipelineLayout layout;
    CHECK(vkCreatePipelineLayout(d.device, &info, nullptr, &layout));
    return layout;
}

// The TLAS (binding 0) and the results (binding 1) as writes into a set; the struct owns what
// they point to (filled in place by `scene_writes`).
struct SceneWrites {
    VkAccelerationStructureKHR top = VK_NULL_HANDLE;
    VkWriteDescriptorSetAccelerationStructureKHR structure{
        VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET_ACCELERATION_STRUCTURE_KHR};
    VkDescriptorBufferInfo buffer{};
    VkWriteDescriptorSet writes[2] = {{VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET},
                                      {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET}};
};
void scene_writes(VkDescriptorSet set, VkAccelerationStructureKHR top, VkBuffer results,
                  SceneWrites& out) {
    out.top = top;
    out.structure.accelerationStructureCount = 1;
    out.structure.pAccelerationStructures = &out.top;
    out.buffer = {results, 0, VK_WHOLE_SIZE};
    out.writes[0].pNext = &out.structure;
    out.writes[0].dstSet = set;
    out.writes[0].dstBinding = 0;
    out.writes[0].descriptorCount = 1;
    out.writes[0].descriptorType = VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR;
    out.writes[1].dstSet = set;
    out.writes[1].dstBinding = 1;
    out.writes[1].descriptorCount = 1;
    out.writes[1].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    out.writes[1].pBufferInfo = &out.buffer;
}

// The same two descriptors as `create_set` writes, through vkUpdateDescriptorSetWithTemplate.
void write_with_template(const Device& d, const Pipelines& p, VkAccelerationStructureKHR top,
                         VkBuffer results) {
    struct Data {
        VkAccelerationStructureKHR top;
        VkDescriptorBufferInfo results;
    } data{top, {results, 0, VK_WHOLE_SIZE}};
    VkDescriptorUpdateTemplateEntry entries[2] = {
        {0, 0, 1, VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR, offsetof(Data, top), 0},
        {1, 0, 1, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, offsetof(Data, results), 0}};
    VkDescriptorUpdateTemplateCreateInfo info{
        VK_STRUCTURE_TYPE_DESCRIPTOR_UPDATE_TEMPLATE_CREATE_INFO};
    info.descriptorUpdateEntryCount = 2;
    info.pDescriptorUpdateEntries = entries;
    info.templateType = VK_DESCRIPTOR_UPDATE_TEMPLATE_TYPE_DESCRIPTOR_SET;
    info.descriptorSetLayout = p.set_layout;
    VkDescriptorUpdateTemplate update;
    CHECK(vkCreateDescriptorUpdateTemplate(d.device, &info, nullptr, &update));
    vkUpdateDescriptorSetWithTemplate(d.device, p.template_set, update, &data);
}

// Binding 0: the TLAS; binding 1: the results. Written with vkUpdateDescriptorSets.
void create_set(const Device& d, Pipelines& p, VkAccelerationStructureKHR top, VkBuffer results) {
    const VkShaderStageFlags stages = kStages;
    VkDescriptorSetLayoutBinding bindings[2] = {{0, VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR,
                                                 1, stages, nullptr},
                                                {1, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1, stages,
                                                 nullptr}};
    VkDescriptorSetLayoutCreateInfo layout{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
    layout.bindingCount = 2;
    layout.pBindings = bindings;
    CHECK(vkCreateDescriptorSetLayout(d.device, &layout, nullptr, &p.set_layout));
    layout.flags = VK_DESCRIPTOR_SET_LAYOUT_CREATE_PUSH_DESCRIPTOR_BIT_KHR;
    VkDescriptorSetLayout push_set_layout;
    CHECK(vkCreateDescriptorSetLayout(d.device, &layout, nullptr, &push_set_layout));
    p.push_layout = pipeline_layout_of(d, push_set_layout);
    p.layout = pipeline_layout_of(d, p.set_layout);
    VkDescriptorPoolSize sizes[2] = {{VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR, 2},
                                     {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 2}};
    VkDescriptorPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
    pool_info.maxSets = 2;
    pool_info.poolSizeCount = 2;
    pool_info.pPoolSizes = sizes;
    VkDescriptorPool pool;
    CHECK(vkCreateDescriptorPool(d.device, &pool_info, nullptr, &pool));
    VkDescriptorSetAllocateInfo allocate{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
    allocate.descriptorPool = pool;
    allocate.descriptorSetCount = 1;
    allocate.pSetLayouts = &p.set_layout;
    CHECK(vkAllocateDescriptorSets(d.device, &allocate, &p.set));
    CHECK(vkAllocateDescriptorSets(d.device, &allocate, &p.template_set));
    SceneWrites scene;
    scene_writes(p.set, top, results, scene);
    vkUpdateDescriptorSets(d.device, 2, scene.writes, 0, nullptr);
    write_with_template(d, p, top, results);
}

VkPipeline compute_pipeline(const Device& d, VkPipelineLayout layout, const uint32_t* code,
                            size_t size, VkPipelineCreateFlags flags = 0) {
    VkComputePipelineCreateInfo info{VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO};
    info.flags = flags;
    info.stage.sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
    info.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
    info.stage.module = shader(d, code, size);
    info.stage.pName = "main";
    info.layout = layout;
    VkPipeline pipeline;
    CHECK(vkCreateComputePipelines(d.device, VK_NULL_HANDLE, 1, &info, nullptr, &pipeline));
    return pipeline;
}

// One vertex shader, rasterizer discard, no attachment (dynamic rendering).
VkPipeline draw_pipeline(const Device& d, VkPipelineLayout layout) {
    VkPipelineShaderStageCreateInfo stage{VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO};
    stage.stage = VK_SHADER_STAGE_VERTEX_BIT;
    stage.module = shader(d, kRayQueryVert, sizeof kRayQueryVert);
    stage.pName = "main";
    VkPipelineVertexInputStateCreateInfo vertex_input{
        VK_STRUCTURE_TYPE_PIPELINE_VERTEX_INPUT_STATE_CREATE_INFO};
    VkPipelineInputAssemblyStateCreateInfo assembly{
        VK_STRUCTURE_TYPE_PIPELINE_INPUT_ASSEMBLY_STATE_CREATE_INFO};
    assembly.topology = VK_PRIMITIVE_TOPOLOGY_POINT_LIST;
    VkPipelineRasterizationStateCreateInfo raster{
        VK_STRUCTURE_TYPE_PIPELINE_RASTERIZATION_STATE_CREATE_INFO};
    raster.rasterizerDiscardEnable = VK_TRUE;
    raster.lineWidth = 1.0f;
    VkPipelineRenderingCreateInfo rendering{VK_STRUCTURE_TYPE_PIPELINE_RENDERING_CREATE_INFO};
    VkGraphicsPipelineCreateInfo info{VK_STRUCTURE_TYPE_GRAPHICS_PIPELINE_CREATE_INFO, &rendering};
    info.stageCount = 1;
    info.pStages = &stage;
    info.pVertexInputState = &vertex_input;
    info.pInputAssemblyState = &assembly;
    info.pRasterizationState = &raster;
    info.layout = layout;
    VkPipeline pipeline;
    CHECK(vkCreateGraphicsPipelines(d.device, VK_NULL_HANDLE, 1, &info, nullptr, &pipeline));
    return pipeline;
}

VkPipeline ray_tracing_pipeline(const Device& d, VkPipelineLayout layout) {
    VkPipelineShaderStageCreateInfo stages[3] = {};
    const VkShaderStageFlagBits kinds[3] = {VK_SHADER_STAGE_RAYGEN_BIT_KHR,
                                            VK_SHADER_STAGE_MISS_BIT_KHR,
                                            VK_SHADER_STAGE_CLOSEST_HIT_BIT_KHR};
    const VkShaderModule modules[3] = {shader(d, kRaysRgen, sizeof kRaysRgen),
                                       shader(d, kRaysRmiss, sizeof kRaysRmiss),
                                       shader(d, kRaysRchit, sizeof kRaysRchit)};
    VkRayTracingShaderGroupCreateInfoKHR groups[3] = {};
    for (uint32_t i = 0; i < 3; ++i) {
        stages[i].sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
        stages[i].stage = kinds[i];
        stages[i].module = modules[i];
        stages[i].pName = "main";
        groups[i].sType = VK_STRUCTURE_TYPE_RAY_TRACING_SHADER_GROUP_CREATE_INFO_KHR;
        groups[i].type = i == 2 ? VK_RAY_TRACING_SHADER_GROUP_TYPE_TRIANGLES_HIT_GROUP_KHR
                                : VK_RAY_TRACING_SHADER_GROUP_TYPE_GENERAL_KHR;
        groups[i].generalShader = i == 2 ? VK_SHADER_UNUSED_KHR : i;
        groups[i].closestHitShader = i == 2 ? 2 : VK_SHADER_UNUSED_KHR;
        groups[i].anyHitShader = VK_SHADER_UNUSED_KHR;
        groups[i].intersectionShader = VK_SHADER_UNUSED_KHR;
    }
    VkRayTracingPipelineCreateInfoKHR info{VK_STRUCTURE_TYPE_RAY_TRACING_PIPELINE_CREATE_INFO_KHR};
    info.stageCount = 3;
    info.pStages = stages;
    info.groupCount = 3;
    info.pGroups = groups;
    info.maxPipelineRayRecursionDepth = 1;
    info.layout = layout;
    VkPipeline pipeline;
    CHECK(d.fn.create_ray_tracing_pipelines(d.device, VK_NULL_HANDLE, VK_NULL_HANDLE, 1, &info,
                                            nullptr, &pipeline));
    return pipeline;
}

// Raygen, miss and hit regions, each at a multiple of shaderGroupBaseAlignment.
struct BindingTable {
    Buffer buffer;
    VkStridedDeviceAddressRegionKHR regions[4] = {};
};

BindingTable binding_table(const Device& d, VkPipeline pipeline) {
    const uint32_t handle_size = d.rt.shaderGroupHandleSize;
    const VkDeviceSize base = d.rt.shaderGroupBaseAlignment;
    const VkDeviceSize stride = align_up(handle_size, d.rt.shaderGroupHandleAlignment);
    std::vector<uint8_t> handles(3 * handle_size);
    CHECK(d.fn.group_handles(d.device, pipeline, 0, 3, handles.size(), handles.data()));
    BindingTable t;
    t.buffer = create_buffer(d, 4 * base, VK_BUFFER_USAGE_SHADER_BINDING_TABLE_BIT_KHR);
    const VkDeviceAddress first = align_up(t.buffer.address, base);
    for (uint32_t g = 0; g < 3; ++g) {
        const VkDeviceAddress at = first + g * base;
        std::memcpy(static_cast<uint8_t*>(t.buffer.mapped) + (at - t.buffer.address),
                    handles.data() + g * handle_size, handle_size);
        t.regions[g] = {at, g == 0 ? align_up(stride, base) : stride,
                        g == 0 ? align_up(stride, base) : stride};
    }
    return t;
}

void record_consumers(const Device& d, VkCommandBuffer cb, const Pipelines& p, const Scene& scene,
                      VkBuffer results, const BindingTable& table, const Buffer& indirect) {
    Constants constants{scene.top.address, 0, 0};
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_COMPUTE, p.ray_query);
    vkCmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_COMPUTE, p.layout, 0, 1, &p.set, 0, nullptr);
    vkCmdPushConstants(cb, p.layout, kStages, 0, sizeof constants, &constants);
    vkCmdDispatch(cb, 1, 1, 1);
    vkCmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_COMPUTE, p.layout, 0, 1, &p.template_set, 0,
                            nullptr);
    vkCmdDispatch(cb, 1, 1, 1);
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_COMPUTE, p.pushed_ray_query);
    SceneWrites pushed;
    scene_writes(VK_NULL_HANDLE, scene.top.handle, results, pushed);
    d.fn.push_descriptor_set(cb, VK_PIPELINE_BIND_POINT_COMPUTE, p.push_layout, 0, 2,
                             pushed.writes);
    vkCmdDispatch(cb, 1, 1, 1);
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_COMPUTE, p.plain);
    vkCmdDispatch(cb, 1, 1, 1);
    VkRenderingInfo rendering{VK_STRUCTURE_TYPE_RENDERING_INFO};
    rendering.renderArea.extent = {1, 1};
    rendering.layerCount = 1;
    vkCmdBeginRendering(cb, &rendering);
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_GRAPHICS, p.draw_ray_query);
    vkCmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_GRAPHICS, p.layout, 0, 1, &p.set, 0,
                            nullptr);
    vkCmdDraw(cb, 1, 1, 0, 0);
    vkCmdEndRendering(cb);
    VkMemoryBarrier written{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
    written.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT;
    written.dstAccessMask = VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT;
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                         VK_PIPELINE_STAGE_RAY_TRACING_SHADER_BIT_KHR, 0, 1, &written, 0, nullptr,
                         0, nullptr);
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_RAY_TRACING_KHR, p.rays);
    vkCmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_RAY_TRACING_KHR, p.layout, 0, 1, &p.set, 0,
                            nullptr);
    constants.first = 2;
    vkCmdPushConstants(cb, p.layout, kStages, 0, sizeof constants, &constants);
    d.fn.trace_rays(cb, &table.regions[0], &table.regions[1], &table.regions[2], &table.regions[3],
                    4, 2, 1);
    if (!d.trace_rays_indirect) return;
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_RAY_TRACING_SHADER_BIT_KHR,
                         VK_PIPELINE_STAGE_RAY_TRACING_SHADER_BIT_KHR, 0, 1, &written, 0, nullptr,
                         0, nullptr);
    constants.first = 10;
    vkCmdPushConstants(cb, p.layout, kStages, 0, sizeof constants, &constants);
    d.fn.trace_rays_indirect(cb, &table.regions[0], &table.regions[1], &table.regions[2],
                             &table.regions[3], indirect.address);
}

void submit_and_wait(const Device& d, VkCommandBuffer cb) {
    VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
    submit.commandBufferCount = 1;
    submit.pCommandBuffers = &cb;
    VkFenceCreateInfo fence_info{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
    VkFence fence;
    CHECK(vkCreateFence(d.device, &fence_info, nullptr, &fence));
    CHECK(vkQueueSubmit(d.queue, 1, &submit, fence));
    CHECK(vkWaitForFences(d.device, 1, &fence, VK_TRUE, UINT64_MAX));
    vkDestroyFence(d.device, fence, nullptr);
}

VkCommandBuffer begin(const Device& d, VkCommandPool pool) {
    VkCommandBufferAllocateInfo allocate{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
    allocate.commandPool = pool;
    allocate.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
    allocate.commandBufferCount = 1;
    VkCommandBuffer cb;
    CHECK(vkAllocateCommandBuffers(d.device, &allocate, &cb));
    VkCommandBufferBeginInfo info{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    info.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    CHECK(vkBeginCommandBuffer(cb, &info));
    return cb;
}

// The results: [0] ray query (1 hit), [1] plain dispatch (7), [18] the draw's ray query (1),
// [2..9] direct rays and [10..17] indirect rays (1 where x + y < 1 for the cell's ray, 2 elsewhere).
bool results_right(const uint32_t* values, bool indirect) {
    bool right = values[0] == 1 && values[1] == 7 && values[18] == 1;
    for (uint32_t cell = 0; cell < 8; ++cell) {
        const float x = (float(cell % 4) + 0.5f) / 4, y = (float(cell / 4) + 0.5f) / 2;
        const uint32_t expected = x + y < 1 ? 1u : 2u;
        right = right && values[2 + cell] == expected;
        if (indirect) right = right && values[10 + cell] == expected;
    }
    return right;
}

// ---- "sources" mode: the other ways a consumer reaches a structure ----------------------------

// A set whose binding 0 (the TLAS) may be written after the set is bound (UPDATE_AFTER_BIND),
// with its own pipeline layout and ray-query pipeline.
struct LateSet {
    VkPipelineLayout layout = VK_NULL_HANDLE;
    VkDescriptorSet set = VK_NULL_HANDLE;
    VkPipeline pipeline = VK_NULL_HANDLE;
};

LateSet late_set(const Device& d) {
    const VkShaderStageFlags stages = kStages;
    VkDescriptorSetLayoutBinding bindings[2] = {{0, VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR,
                                                 1, stages, nullptr},
                                                {1, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1, stages,
                                                 nullptr}};
    const VkDescriptorBindingFlags flags[2] = {VK_DESCRIPTOR_BINDING_UPDATE_AFTER_BIND_BIT, 0};
    VkDescriptorSetLayoutBindingFlagsCreateInfo binding_flags{
        VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_BINDING_FLAGS_CREATE_INFO};
    binding_flags.bindingCount = 2;
    binding_flags.pBindingFlags = flags;
    VkDescriptorSetLayoutCreateInfo layout{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO,
                                           &binding_flags};
    layout.flags = VK_DESCRIPTOR_SET_LAYOUT_CREATE_UPDATE_AFTER_BIND_POOL_BIT;
    layout.bindingCount = 2;
    layout.pBindings = bindings;
    VkDescriptorSetLayout set_layout;
    CHECK(vkCreateDescriptorSetLayout(d.device, &layout, nullptr, &set_layout));
    LateSet late;
    late.layout = pipeline_layout_of(d, set_layout);
    VkDescriptorPoolSize sizes[2] = {{VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR, 1},
                                     {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1}};
    VkDescriptorPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
    pool_info.flags = VK_DESCRIPTOR_POOL_CREATE_UPDATE_AFTER_BIND_BIT;
    pool_info.maxSets = 1;
    pool_info.poolSizeCount = 2;
    pool_info.pPoolSizes = sizes;
    VkDescriptorPool pool;
    CHECK(vkCreateDescriptorPool(d.device, &pool_info, nullptr, &pool));
    VkDescriptorSetAllocateInfo allocate{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
    allocate.descriptorPool = pool;
    allocate.descriptorSetCount = 1;
    allocate.pSetLayouts = &set_layout;
    CHECK(vkAllocateDescriptorSets(d.device, &allocate, &late.set));
    late.pipeline = compute_pipeline(d, late.layout, kRayQueryComp, sizeof kRayQueryComp);
    return late;
}

// Command buffer 1: the set bound with vkCmdBindDescriptorSets2KHR and the TLAS address pushed
// with vkCmdPushConstants2KHR. Command buffer 2: the late set bound while it names `other`, then
// (after recording, before submission) rewritten to name the TLAS. Command buffer 3: the TLAS
// pushed with vkCmdPushDescriptorSet2KHR. Each must reach the TLAS.
bool run_sources(const Device& d, VkCommandPool pool, const Scene& scene, const Buffer& results,
                 const Pipelines& p, const LateSet& late, VkAccelerationStructureKHR other) {
    uint32_t* values = static_cast<uint32_t*>(results.mapped);
    VkCommandBuffer cb = begin(d, pool);
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_COMPUTE, p.ray_query);
    VkBindDescriptorSetsInfoKHR bind{VK_STRUCTURE_TYPE_BIND_DESCRIPTOR_SETS_INFO_KHR};
    bind.stageFlags = VK_SHADER_STAGE_COMPUTE_BIT;
    bind.layout = p.layout;
    bind.descriptorSetCount = 1;
    bind.pDescriptorSets = &p.set;
    d.fn.bind_descriptor_sets2(cb, &bind);
    const Constants constants{scene.top.address, 0, 0};
    VkPushConstantsInfoKHR push{VK_STRUCTURE_TYPE_PUSH_CONSTANTS_INFO_KHR};
    push.layout = p.layout;
    push.stageFlags = kStages;
    push.size = sizeof constants;
    push.pValues = &constants;
    d.fn.push_constants2(cb, &push);
    vkCmdDispatch(cb, 1, 1, 1);
    CHECK(vkEndCommandBuffer(cb));
    submit_and_wait(d, cb);
    bool right = values[0] == 1;
    values[0] = 0;

    SceneWrites before;
    scene_writes(late.set, other, results.buffer, before);
    vkUpdateDescriptorSets(d.device, 2, before.writes, 0, nullptr);
    cb = begin(d, pool);
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_COMPUTE, late.pipeline);
    vkCmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_COMPUTE, late.layout, 0, 1, &late.set, 0,
                            nullptr);
    vkCmdDispatch(cb, 1, 1, 1);
    CHECK(vkEndCommandBuffer(cb));
    SceneWrites after;
    scene_writes(late.set, scene.top.handle, results.buffer, after);
    vkUpdateDescriptorSets(d.device, 1, after.writes, 0, nullptr);  // binding 0 only
    submit_and_wait(d, cb);
    right = right && values[0] == 1;
    values[0] = 0;

    cb = begin(d, pool);
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_COMPUTE, p.pushed_ray_query);
    SceneWrites pushed;
    scene_writes(VK_NULL_HANDLE, scene.top.handle, results.buffer, pushed);
    VkPushDescriptorSetInfoKHR push_set{VK_STRUCTURE_TYPE_PUSH_DESCRIPTOR_SET_INFO_KHR};
    push_set.stageFlags = VK_SHADER_STAGE_COMPUTE_BIT;
    push_set.layout = p.push_layout;
    push_set.descriptorWriteCount = 2;
    push_set.pDescriptorWrites = pushed.writes;
    d.fn.push_descriptor_set2(cb, &push_set);
    vkCmdDispatch(cb, 1, 1, 1);
    CHECK(vkEndCommandBuffer(cb));
    submit_and_wait(d, cb);
    return right && values[0] == 1;
}

// The sources mode: OUT.json names the TLAS, the other TLAS and the two pipelines.
VkCommandPool command_pool(const Device& d) {
    VkCommandPoolCreateInfo info{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
    info.queueFamilyIndex = d.family;
    VkCommandPool pool;
    CHECK(vkCreateCommandPool(d.device, &info, nullptr, &pool));
    return pool;
}

// The end of a mode: its OUT.json (one printf line), the device idle, and the exit the test
// reads: "ok" when the shaders' results are right.
[[gnu::format(printf, 4, 5)]] int finish_mode(const Device& d, const char* out_path, bool right,
                                              const char* format, ...) {
    FILE* out = std::fopen(out_path, "w");
    if (!out) fail("cannot write OUT.json");
    va_list args;
    va_start(args, format);
    std::vfprintf(out, format, args);
    va_end(args);
    std::fclose(out);
    vkDeviceWaitIdle(d.device);
    if (!right) fail("the shaders' results are wrong");
    std::printf("ok\n");
    return 0;
}

int sources_main(const char* out_path) {
    Device d = create_device();
    const VkCommandPool pool = command_pool(d);
    VkCommandBuffer build_cb = begin(d, pool);
    const Scene scene = build_scene(d, build_cb);
    // A second top level over the same instance: what the late set names when it is bound.
    VkAccelerationStructureGeometryKHR instances{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    instances.geometryType = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    instances.geometry.instances.sType =
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_INSTANCES_DATA_KHR;
    instances.geometry.instances.data.deviceAddress = scene.instances.address;
    const Structure other =
        build_structure(d, build_cb, VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR, instances, 1);
    CHECK(vkEndCommandBuffer(build_cb));
    submit_and_wait(d, build_cb);

    Buffer results = create_buffer(d, 32 * sizeof(uint32_t), VK_BUFFER_USAGE_STORAGE_BUFFER_BIT);
    Pipelines p;
    create_set(d, p, scene.top.handle, results.buffer);
    p.ray_query = compute_pipeline(d, p.layout, kRayQueryComp, sizeof kRayQueryComp);
    p.pushed_ray_query = compute_pipeline(d, p.push_layout, kRayQueryComp, sizeof kRayQueryComp);
    const LateSet late = late_set(d);
    const bool right = run_sources(d, pool, scene, results, p, late, other.handle);
    return finish_mode(d, out_path, right,
                       "{\"topLevel\": %llu, \"topLevelAddress\": %llu, \"otherTopLevel\": %llu, "
                       "\"rayQueryPipeline\": %llu, \"updateAfterBindPipeline\": %llu, "
                       "\"pushedRayQueryPipeline\": %llu}\n",
                       (unsigned long long)(uint64_t)scene.top.handle,
                       (unsigned long long)scene.top.address,
                       (unsigned long long)(uint64_t)other.handle,
                       (unsigned long long)(uint64_t)p.ray_query,
                       (unsigned long long)(uint64_t)late.pipeline,
                       (unsigned long long)(uint64_t)p.pushed_ray_query);
}

// ---- "descriptor-buffer" mode: the TLAS descriptor in a descriptor buffer -----------------------

// The set layout (binding 0 the TLAS, binding 1 the results) for descriptor buffers, written at
// `base` bytes into `descriptors` with vkGetDescriptorEXT; the ray-query pipeline over it.
struct BufferSet {
    VkPipelineLayout layout = VK_NULL_HANDLE;
    VkPipeline pipeline = VK_NULL_HANDLE;
    Buffer descriptors;
    VkDeviceSize base = 0;
};

BufferSet buffer_set(const Device& d, const Structure& top, const Buffer& results) {
    const VkShaderStageFlags stages = kStages;
    VkDescriptorSetLayoutBinding bindings[2] = {{0, VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR,
                                                 1, stages, nullptr},
                                                {1, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1, stages,
                                                 nullptr}};
    VkDescriptorSetLayoutCreateInfo info{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
    info.flags = VK_DESCRIPTOR_SET_LAYOUT_CREATE_DESCRIPTOR_BUFFER_BIT_EXT;
    info.bindingCount = 2;
    info.pBindings = bindings;
    VkDescriptorSetLayout set_layout;
    CHECK(vkCreateDescriptorSetLayout(d.device, &info, nullptr, &set_layout));
    BufferSet b;
    b.layout = pipeline_layout_of(d, set_layout);
    b.pipeline = compute_pipeline(d, b.layout, kRayQueryComp, sizeof kRayQueryComp,
                                  VK_PIPELINE_CREATE_DESCRIPTOR_BUFFER_BIT_EXT);
    VkDeviceSize size = 0, offsets[2] = {0, 0};
    d.fn.set_layout_size(d.device, set_layout, &size);
    for (uint32_t binding = 0; binding < 2; ++binding)
        d.fn.binding_offset(d.device, set_layout, binding, &offsets[binding]);
    // The set starts past the buffer's start, so that the offset given at binding counts.
    b.base = align_up(64, d.descriptor_buffer_properties.descriptorBufferOffsetAlignment);
    b.descriptors =
        create_buffer(d, b.base + size, VK_BUFFER_USAGE_RESOURCE_DESCRIPTOR_BUFFER_BIT_EXT);
    auto* bytes = static_cast<uint8_t*>(b.descriptors.mapped) + b.base;
    VkDescriptorGetInfoEXT structure{VK_STRUCTURE_TYPE_DESCRIPTOR_GET_INFO_EXT};
    structure.type = VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR;
    structure.data.accelerationStructure = top.address;
    d.fn.get_descriptor(d.device, &structure,
                        d.descriptor_buffer_properties.accelerationStructureDescriptorSize,
                        bytes + offsets[0]);
    VkDescriptorAddressInfoEXT range{VK_STRUCTURE_TYPE_DESCRIPTOR_ADDRESS_INFO_EXT};
    range.address = results.address;
    range.range = 32 * sizeof(uint32_t);
    VkDescriptorGetInfoEXT storage{VK_STRUCTURE_TYPE_DESCRIPTOR_GET_INFO_EXT};
    storage.type = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    storage.data.pStorageBuffer = &range;
    d.fn.get_descriptor(d.device, &storage,
                        d.descriptor_buffer_properties.storageBufferDescriptorSize,
                        bytes + offsets[1]);
    return b;
}

// One ray-query dispatch whose set 0 comes from the descriptor buffer at `base`.
bool run_descriptor_buffer(const Device& d, VkCommandPool pool, const BufferSet& b,
                           const Buffer& results) {
    VkCommandBuffer cb = begin(d, pool);
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_COMPUTE, b.pipeline);
    VkDescriptorBufferBindingInfoEXT binding{VK_STRUCTURE_TYPE_DESCRIPTOR_BUFFER_BINDING_INFO_EXT};
    binding.address = b.descriptors.address;
    binding.usage = VK_BUFFER_USAGE_RESOURCE_DESCRIPTOR_BUFFER_BIT_EXT;
    d.fn.bind_descriptor_buffers(cb, 1, &binding);
    const uint32_t buffer_index = 0;
    d.fn.set_descriptor_buffer_offsets(cb, VK_PIPELINE_BIND_POINT_COMPUTE, b.layout, 0, 1,
                                       &buffer_index, &b.base);
    vkCmdDispatch(cb, 1, 1, 1);
    CHECK(vkEndCommandBuffer(cb));
    submit_and_wait(d, cb);
    return static_cast<const uint32_t*>(results.mapped)[0] == 1;
}

// The descriptor-buffer mode: OUT.json names the TLAS and the pipeline.
int descriptor_buffer_main(const char* out_path) {
    Device d = create_device(true);
    const VkCommandPool pool = command_pool(d);
    VkCommandBuffer build_cb = begin(d, pool);
    const Scene scene = build_scene(d, build_cb);
    CHECK(vkEndCommandBuffer(build_cb));
    submit_and_wait(d, build_cb);
    Buffer results = create_buffer(d, 32 * sizeof(uint32_t), VK_BUFFER_USAGE_STORAGE_BUFFER_BIT);
    const BufferSet b = buffer_set(d, scene.top, results);
    const bool right = run_descriptor_buffer(d, pool, b, results);
    return finish_mode(
        d, out_path, right,
        "{\"topLevel\": %llu, \"topLevelAddress\": %llu, \"descriptorBufferPipeline\": "
        "%llu}\n",
        (unsigned long long)(uint64_t)scene.top.handle, (unsigned long long)scene.top.address,
        (unsigned long long)(uint64_t)b.pipeline);
}

// ---- "address-in-buffer" mode: the TLAS address read from a storage buffer ----------------------

// What address_in_buffer.comp reads at set 0, binding 0.
struct SceneAddress {
    VkDeviceAddress address;
    uint32_t trace;  // 0: the shader does not convert `address`
    uint32_t slot;   // where it writes its result
};

// The set layout (binding 0 the scene address, binding 1 the results), as a set and pushed.
struct AddressSets {
    VkPipelineLayout layout = VK_NULL_HANDLE, push_layout = VK_NULL_HANDLE;
    VkPipeline pipeline = VK_NULL_HANDLE, pushed_pipeline = VK_NULL_HANDLE;
    VkDescriptorSet bound = VK_NULL_HANDLE, not_an_address = VK_NULL_HANDLE;
    // address_in_uniform.comp: binding 0 a dynamic uniform buffer.
    VkPipelineLayout uniform_layout = VK_NULL_HANDLE;
    VkPipeline uniform_pipeline = VK_NULL_HANDLE;
    VkDescriptorSet uniform = VK_NULL_HANDLE;
};

// The dynamic offset of the uniform buffer's SceneAddress: 256 satisfies every device's
// minUniformBufferOffsetAlignment, and bytes 0..255 hold no address.
constexpr VkDeviceSize kUniformDynamicOffset = 256;

void write_address_set(const Device& d, VkDescriptorSet set, VkBuffer scene, VkBuffer results) {
    VkDescriptorBufferInfo infos[2] = {{scene, 0, VK_WHOLE_SIZE}, {results, 0, VK_WHOLE_SIZE}};
    VkWriteDescriptorSet writes[2] = {{VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET},
                                      {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET}};
    for (uint32_t i = 0; i < 2; ++i) {
        writes[i].dstSet = set;
        writes[i].dstBinding = i;
        writes[i].descriptorCount = 1;
        writes[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
        writes[i].pBufferInfo = &infos[i];
    }
    vkUpdateDescriptorSets(d.device, 2, writes, 0, nullptr);
}

// The uniform-buffer set of `a`: binding 0 `uniform` (dynamic, one SceneAddress wide), binding
// 1 the results.
void add_uniform_address_set(const Device& d, VkBuffer uniform, VkBuffer results, AddressSets& a) {
    VkDescriptorSetLayoutBinding bindings[2] = {{0, VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER_DYNAMIC, 1,
                                                 VK_SHADER_STAGE_COMPUTE_BIT, nullptr},
                                                {1, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1,
                                                 VK_SHADER_STAGE_COMPUTE_BIT, nullptr}};
    VkDescriptorSetLayoutCreateInfo info{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
    info.bindingCount = 2;
    info.pBindings = bindings;
    VkDescriptorSetLayout set_layout;
    CHECK(vkCreateDescriptorSetLayout(d.device, &info, nullptr, &set_layout));
    VkPipelineLayoutCreateInfo layout{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
    layout.setLayoutCount = 1;
    layout.pSetLayouts = &set_layout;
    CHECK(vkCreatePipelineLayout(d.device, &layout, nullptr, &a.uniform_layout));
    a.uniform_pipeline =
        compute_pipeline(d, a.uniform_layout, kAddressInUniformComp, sizeof kAddressInUniformComp);
    VkDescriptorPoolSize sizes[2] = {{VK_DESCRIPTOR_TYPE_UNIFORM_BUFFER_DYNAMIC, 1},
                                     {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1}};
    VkDescriptorPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
    pool_info.maxSets = 1;
    pool_info.poolSizeCount = 2;
    pool_info.pPoolSizes = sizes;
    VkDescriptorPool pool;
    CHECK(vkCreateDescriptorPool(d.device, &pool_info, nullptr, &pool));
    VkDescriptorSetAllocateInfo allocate{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
    allocate.descriptorPool = pool;
    allocate.descriptorSetCount = 1;
    allocate.pSetLayouts = &set_layout;
    CHECK(vkAllocateDescriptorSets(d.device, &allocate, &a.uniform));
    VkDescriptorBufferInfo infos[2] = {{uniform, 0, sizeof(SceneAddress)},
                                       {results, 0, VK_WHOLE_SIZE}};
    VkWriteDescriptorSet writes[2] = {{VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET},
                                      {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET}};
    for (uint32_t i = 0; i < 2; ++i) {
        writes[i].dstSet = a.uniform;
        writes[i].dstBinding = i;
        writes[i].descriptorCount = 1;
        writes[i].descriptorType = bindings[i].descriptorType;
        writes[i].pBufferInfo = &infos[i];
    }
    vkUpdateDescriptorSets(d.device, 2, writes, 0, nullptr);
}

AddressSets address_sets(const Device& d, VkBuffer bound, VkBuffer not_an_address,
                         VkBuffer results) {
    VkDescriptorSetLayoutBinding bindings[2] = {{0, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1,
                                                 VK_SHADER_STAGE_COMPUTE_BIT, nullptr},
                                                {1, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1,
                                                 VK_SHADER_STAGE_COMPUTE_BIT, nullptr}};
    VkDescriptorSetLayoutCreateInfo info{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
    info.bindingCount = 2;
    info.pBindings = bindings;
    VkDescriptorSetLayout set_layout, push_set_layout;
    CHECK(vkCreateDescriptorSetLayout(d.device, &info, nullptr, &set_layout));
    info.flags = VK_DESCRIPTOR_SET_LAYOUT_CREATE_PUSH_DESCRIPTOR_BIT_KHR;
    CHECK(vkCreateDescriptorSetLayout(d.device, &info, nullptr, &push_set_layout));
    AddressSets a;
    // No push constants: the address can only come from the buffer.
    VkPipelineLayoutCreateInfo layout{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
    layout.setLayoutCount = 1;
    layout.pSetLayouts = &set_layout;
    CHECK(vkCreatePipelineLayout(d.device, &layout, nullptr, &a.layout));
    layout.pSetLayouts = &push_set_layout;
    CHECK(vkCreatePipelineLayout(d.device, &layout, nullptr, &a.push_layout));
    a.pipeline = compute_pipeline(d, a.layout, kAddressInBufferComp, sizeof kAddressInBufferComp);
    a.pushed_pipeline =
        compute_pipeline(d, a.push_layout, kAddressInBufferComp, sizeof kAddressInBufferComp);
    VkDescriptorPoolSize size{VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 4};
    VkDescriptorPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
    pool_info.maxSets = 2;
    pool_info.poolSizeCount = 1;
    pool_info.pPoolSizes = &size;
    VkDescriptorPool pool;
    CHECK(vkCreateDescriptorPool(d.device, &pool_info, nullptr, &pool));
    VkDescriptorSetLayout layouts[2] = {set_layout, set_layout};
    VkDescriptorSet sets[2];
    VkDescriptorSetAllocateInfo allocate{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
    allocate.descriptorPool = pool;
    allocate.descriptorSetCount = 2;
    allocate.pSetLayouts = layouts;
    CHECK(vkAllocateDescriptorSets(d.device, &allocate, sets));
    a.bound = sets[0];
    a.not_an_address = sets[1];
    write_address_set(d, a.bound, bound, results);
    write_address_set(d, a.not_an_address, not_an_address, results);
    return a;
}

// Dispatch 1: the bound set's buffer holds the TLAS address. Dispatch 2: a buffer whose bytes
// are no structure's address (not traced). Dispatch 3: pushed descriptors; their buffer gets
// the address between recording and submission. Dispatch 4: a dynamic uniform buffer, the
// address at the dynamic offset. Results 1, 3, 1, 1 in slots 0, 1, 2, 3.
bool run_address_in_buffer(const Device& d, VkCommandPool pool, const AddressSets& a,
                           const Buffer& bound, const Buffer& not_an_address, const Buffer& late,
                           const Buffer& uniform, const Buffer& results, VkDeviceAddress top) {
    const SceneAddress in_bound{top, 1, 0}, no_address{top + 8, 0, 1}, not_yet{0, 1, 2},
        in_uniform{top, 1, 3};
    std::memcpy(bound.mapped, &in_bound, sizeof in_bound);
    std::memcpy(static_cast<uint8_t*>(uniform.mapped) + kUniformDynamicOffset, &in_uniform,
                sizeof in_uniform);
    std::memcpy(not_an_address.mapped, &no_address, sizeof no_address);
    std::memcpy(late.mapped, &not_yet, sizeof not_yet);
    VkCommandBuffer cb = begin(d, pool);
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_COMPUTE, a.pipeline);
    vkCmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_COMPUTE, a.layout, 0, 1, &a.bound, 0,
                            nullptr);
    vkCmdDispatch(cb, 1, 1, 1);
    vkCmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_COMPUTE, a.layout, 0, 1, &a.not_an_address,
                            0, nullptr);
    vkCmdDispatch(cb, 1, 1, 1);
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_COMPUTE, a.pushed_pipeline);
    VkDescriptorBufferInfo infos[2] = {{late.buffer, 0, VK_WHOLE_SIZE},
                                       {results.buffer, 0, VK_WHOLE_SIZE}};
    VkWriteDescriptorSet writes[2] = {{VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET},
                                      {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET}};
    for (uint32_t i = 0; i < 2; ++i) {
        writes[i].dstBinding = i;
        writes[i].descriptorCount = 1;
        writes[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
        writes[i].pBufferInfo = &infos[i];
    }
    d.fn.push_descriptor_set(cb, VK_PIPELINE_BIND_POINT_COMPUTE, a.push_layout, 0, 2, writes);
    vkCmdDispatch(cb, 1, 1, 1);
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_COMPUTE, a.uniform_pipeline);
    const uint32_t dynamic_offset = uint32_t(kUniformDynamicOffset);
    vkCmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_COMPUTE, a.uniform_layout, 0, 1, &a.uniform,
                            1, &dynamic_offset);
    vkCmdDispatch(cb, 1, 1, 1);
    CHECK(vkEndCommandBuffer(cb));
    const SceneAddress now{top, 1, 2};
    std::memcpy(late.mapped, &now, sizeof now);
    submit_and_wait(d, cb);
    const auto* values = static_cast<const uint32_t*>(results.mapped);
    return values[0] == 1 && values[1] == 3 && values[2] == 1 && values[3] == 1;
}

// The address-in-buffer mode: OUT.json names the TLAS, the two pipelines and the buffers.
int address_in_buffer_main(const char* out_path) {
    Device d = create_device();
    const VkCommandPool pool = command_pool(d);
    VkCommandBuffer build_cb = begin(d, pool);
    const Scene scene = build_scene(d, build_cb);
    CHECK(vkEndCommandBuffer(build_cb));
    submit_and_wait(d, build_cb);
    Buffer results = create_buffer(d, 32 * sizeof(uint32_t), VK_BUFFER_USAGE_STORAGE_BUFFER_BIT);
    const Buffer bound = create_buffer(d, sizeof(SceneAddress), VK_BUFFER_USAGE_STORAGE_BUFFER_BIT);
    const Buffer not_an_address =
        create_buffer(d, sizeof(SceneAddress), VK_BUFFER_USAGE_STORAGE_BUFFER_BIT);
    const Buffer late = create_buffer(d, sizeof(SceneAddress), VK_BUFFER_USAGE_STORAGE_BUFFER_BIT);
    const Buffer uniform = create_buffer(d, kUniformDynamicOffset + sizeof(SceneAddress),
                                         VK_BUFFER_USAGE_UNIFORM_BUFFER_BIT);
    AddressSets a = address_sets(d, bound.buffer, not_an_address.buffer, results.buffer);
    add_uniform_address_set(d, uniform.buffer, results.buffer, a);
    const bool right = run_address_in_buffer(d, pool, a, bound, not_an_address, late, uniform,
                                             results, scene.top.address);
    return finish_mode(d, out_path, right,
                       "{\"topLevel\": %llu, \"topLevelAddress\": %llu, \"addressPipeline\": %llu, "
                       "\"pushedAddressPipeline\": %llu, \"uniformAddressPipeline\": %llu}\n",
                       (unsigned long long)(uint64_t)scene.top.handle,
                       (unsigned long long)scene.top.address,
                       (unsigned long long)(uint64_t)a.pipeline,
                       (unsigned long long)(uint64_t)a.pushed_pipeline,
                       (unsigned long long)(uint64_t)a.uniform_pipeline);
}

}  // namespace

int main(int argc, char** argv) {
    if (argc == 3 && std::strcmp(argv[2], "address-in-buffer") == 0)
        return address_in_buffer_main(argv[1]);
    if (argc == 3 && std::strcmp(argv[2], "sources") == 0) return sources_main(argv[1]);
    if (argc == 3 && std::strcmp(argv[2], "descriptor-buffer") == 0)
        return descriptor_buffer_main(argv[1]);
    if (argc != 2) {
        std::fprintf(stderr,
                     "usage: ray_consumers_app OUT.json "
                     "[sources|descriptor-buffer|address-in-buffer]\n");
        return 2;
    }
    Device d = create_device();
    const VkCommandPool pool = command_pool(d);

    VkCommandBuffer build_cb = begin(d, pool);
    const Scene scene = build_scene(d, build_cb);
    CHECK(vkEndCommandBuffer(build_cb));
    submit_and_wait(d, build_cb);

    Buffer results = create_buffer(d, 32 * sizeof(uint32_t), VK_BUFFER_USAGE_STORAGE_BUFFER_BIT);
    Buffer indirect = create_buffer(d, sizeof(VkTraceRaysIndirectCommandKHR),
                                    VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT);
    const VkTraceRaysIndirectCommandKHR dimensions{4, 2, 1};
    std::memcpy(indirect.mapped, &dimensions, sizeof dimensions);
    Pipelines p;
    create_set(d, p, scene.top.handle, results.buffer);
    p.ray_query = compute_pipeline(d, p.layout, kRayQueryComp, sizeof kRayQueryComp);
    p.pushed_ray_query = compute_pipeline(d, p.push_layout, kRayQueryComp, sizeof kRayQueryComp);
    p.plain = compute_pipeline(d, p.layout, kPlainComp, sizeof kPlainComp);
    p.draw_ray_query = draw_pipeline(d, p.layout);
    p.rays = ray_tracing_pipeline(d, p.layout);
    const BindingTable table = binding_table(d, p.rays);

    VkCommandBuffer cb = begin(d, pool);
    record_consumers(d, cb, p, scene, results.buffer, table, indirect);
    CHECK(vkEndCommandBuffer(cb));
    submit_and_wait(d, cb);

    const bool right =
        results_right(static_cast<const uint32_t*>(results.mapped), d.trace_rays_indirect);
    FILE* out = std::fopen(argv[1], "w");
    if (!out) fail("cannot write OUT.json");
    std::fprintf(out,
                 "{\"topLevel\": %llu, \"topLevelAddress\": %llu, \"bottomLevel\": %llu, "
                 "\"rayQueryPipeline\": %llu, \"pushedRayQueryPipeline\": %llu, \"drawPipeline\": "
                 "%llu, \"plainPipeline\": "
                 "%llu, \"rayTracingPipeline\": "
                 "%llu, \"raygenAddress\": %llu, \"indirectAddress\": %llu, \"indirect\": %s, "
                 "\"results\": %s}\n",
                 (unsigned long long)(uint64_t)scene.top.handle,
                 (unsigned long long)scene.top.address,
                 (unsigned long long)(uint64_t)scene.bottom.handle,
                 (unsigned long long)(uint64_t)p.ray_query,
                 (unsigned long long)(uint64_t)p.pushed_ray_query,
                 (unsigned long long)(uint64_t)p.draw_ray_query,
                 (unsigned long long)(uint64_t)p.plain, (unsigned long long)(uint64_t)p.rays,
                 (unsigned long long)table.regions[0].deviceAddress,
                 (unsigned long long)(d.trace_rays_indirect ? indirect.address : 0),
                 d.trace_rays_indirect ? "true" : "false", right ? "true" : "false");
    std::fclose(out);
    vkDeviceWaitIdle(d.device);
    // The rest is reclaimed with the process: the test needs the capture, not a clean teardown.
    if (!right) fail("the shaders' results are wrong");
    std::printf("ok\n");
    return 0;
}
