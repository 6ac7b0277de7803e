// SPDX-License-Identifier: Apache-2.0
// rt_frame_loop: a headless ray-traced frame loop on KHR acceleration structures (README.md).
// Per frame: host-animated vertices copied to a device-local buffer, a barrier, one BLAS per mesh
// built into the frame's pool slot, a TLAS over them, a barrier, one ray query per pixel into the
// frame's pixel buffer; frames in flight guarded by fences, each submission marked with
// VkFrameBoundaryEXT where the device has VK_EXT_frame_boundary.
#include "frame_scene.h"
#include "trace_pixels_spirv.h"

#include <CLI/CLI.hpp>
#include <clastrace/vk_cluster_abi.h>
#include <clastrace/vk_frame_boundary_abi.h>
#include <vulkan/vulkan.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

namespace rt_frame_loop {
namespace {

constexpr uint32_t kRingSlots = 2;  // frames in flight
constexpr VkDeviceSize kAlignment = 256;

[[noreturn]] void fail(const char* what, VkResult result) {
    std::fprintf(stderr, "rt_frame_loop: %s failed (VkResult %d)\n", what, int(result));
    std::exit(2);
}
#define CHECK(call)                                                  \
    do {                                                             \
        if (VkResult r_ = (call); r_ != VK_SUCCESS) fail(#call, r_); \
    } while (0)

VkDeviceSize align_up(VkDeviceSize v, VkDeviceSize a) { return (v + a - 1) / a * a; }

struct Buffer {
    VkBuffer buffer = VK_NULL_HANDLE;
    VkDeviceMemory memory = VK_NULL_HANDLE;
    void* mapped = nullptr;
    VkDeviceAddress address = 0;
};

struct Functions {
    PFN_vkGetAccelerationStructureBuildSizesKHR build_sizes;
    PFN_vkCreateAccelerationStructureKHR create_as;
    PFN_vkDestroyAccelerationStructureKHR destroy_as;
    PFN_vkCmdBuildAccelerationStructuresKHR cmd_build;
    PFN_vkGetAccelerationStructureDeviceAddressKHR as_address;
    // --cluster-blas: VK_NV_cluster_acceleration_structure (served by the clastrace layer).
    PFN_vkGetClusterAccelerationStructureBuildSizesNV cluster_sizes;
    PFN_vkCmdBuildClusterAccelerationStructureIndirectNV cmd_build_clusters;
};

struct Context {
    VkInstance instance = VK_NULL_HANDLE;
    VkPhysicalDevice physical = VK_NULL_HANDLE;
    VkDevice device = VK_NULL_HANDLE;
    VkQueue queue = VK_NULL_HANDLE;
    uint32_t family = 0;
    VkPhysicalDeviceMemoryProperties memory{};
    VkDeviceSize scratch_alignment = kAlignment;
    bool frame_boundary = false;
    bool clusters = false;                        // --cluster-blas
    bool implicit_blas = false;                   // --implicit: cluster BLASes packed by the build
    VkDeviceSize cluster_alignment = kAlignment;  // CLAS and cluster BLAS destinations
    Functions fn{};
};

bool has_extension(const std::vector<VkExtensionProperties>& all, const char* name) {
    return std::any_of(all.begin(), all.end(), [&](const VkExtensionProperties& e) {
        return !std::strcmp(e.extensionName, name);
    });
}

// Exit 3 when no device has what the loop needs (run it on lavapipe 25 or a GPU with ray queries;
// with --cluster-blas also VK_NV_cluster_acceleration_structure, which the clastrace capture layer
// serves where the driver lacks it).
void create_context(Context& c) {
    VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
    app.pApplicationName = "rt_frame_loop";
    app.apiVersion = VK_API_VERSION_1_2;
    VkInstanceCreateInfo ici{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
    ici.pApplicationInfo = &app;
    CHECK(vkCreateInstance(&ici, nullptr, &c.instance));
    uint32_t count = 0;
    vkEnumeratePhysicalDevices(c.instance, &count, nullptr);
    std::vector<VkPhysicalDevice> devices(count);
    vkEnumeratePhysicalDevices(c.instance, &count, devices.data());
    std::vector<VkExtensionProperties> extensions;
    for (VkPhysicalDevice pd : devices) {
        uint32_t n = 0;
        vkEnumerateDeviceExtensionProperties(pd, nullptr, &n, nullptr);
        std::vector<VkExtensionProperties> list(n);
        vkEnumerateDeviceExtensionProperties(pd, nullptr, &n, list.data());
        if (has_extension(list, VK_KHR_ACCELERATION_STRUCTURE_EXTENSION_NAME) &&
            has_extension(list, VK_KHR_RAY_QUERY_EXTENSION_NAME) &&
            (!c.clusters ||
             has_extension(list, VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME))) {
            c.physical = pd;
            extensions = list;
            break;
        }
    }
    if (!c.physical) {
        std::fprintf(stderr,
                     "rt_frame_loop: no device with VK_KHR_acceleration_structure and "
                     "VK_KHR_ray_query%s\n",
                     c.clusters ? " and VK_NV_cluster_acceleration_structure (--cluster-blas: "
                                  "run it under `clastrace capture`, whose layer serves the "
                                  "extension)"
                                : "");
        std::exit(3);
    }
    vkGetPhysicalDeviceMemoryProperties(c.physical, &c.memory);
    VkPhysicalDeviceClusterAccelerationStructurePropertiesNV cluster_properties{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV};
    VkPhysicalDeviceAccelerationStructurePropertiesKHR as_properties{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ACCELERATION_STRUCTURE_PROPERTIES_KHR,
        c.clusters ? &cluster_properties : nullptr};
    VkPhysicalDeviceProperties2 properties{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2,
                                           &as_properties};
    vkGetPhysicalDeviceProperties2(c.physical, &properties);
    c.scratch_alignment = std::max<VkDeviceSize>(
        {kAlignment, as_properties.minAccelerationStructureScratchOffsetAlignment,
         cluster_properties.clusterScratchByteAlignment});
    c.cluster_alignment =
        std::max<VkDeviceSize>({kAlignment, cluster_properties.clusterByteAlignment,
                                cluster_properties.clusterBottomLevelByteAlignment});
    uint32_t family_count = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(c.physical, &family_count, nullptr);
    std::vector<VkQueueFamilyProperties> families(family_count);
    vkGetPhysicalDeviceQueueFamilyProperties(c.physical, &family_count, families.data());
    while (c.family < family_count && !(families[c.family].queueFlags & VK_QUEUE_COMPUTE_BIT))
        ++c.family;
    c.frame_boundary = has_extension(extensions, VK_EXT_FRAME_BOUNDARY_EXTENSION_NAME);

    std::vector<const char*> enabled = {VK_KHR_ACCELERATION_STRUCTURE_EXTENSION_NAME,
                                        VK_KHR_DEFERRED_HOST_OPERATIONS_EXTENSION_NAME,
                                        VK_KHR_RAY_QUERY_EXTENSION_NAME};
    if (c.frame_boundary) enabled.push_back(VK_EXT_FRAME_BOUNDARY_EXTENSION_NAME);
    if (c.clusters) enabled.push_back(VK_NV_CLUSTER_ACCELERATION_STRUCTURE_EXTENSION_NAME);
    VkPhysicalDeviceClusterAccelerationStructureFeaturesNV cluster_features{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_FEATURES_NV, nullptr,
        VK_TRUE};
    VkPhysicalDeviceFrameBoundaryFeaturesEXT boundary{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FRAME_BOUNDARY_FEATURES_EXT,
        c.clusters ? &cluster_features : nullptr, VK_TRUE};
    VkPhysicalDeviceRayQueryFeaturesKHR ray_query{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_RAY_QUERY_FEATURES_KHR,
        c.frame_boundary ? static_cast<void*>(&boundary)
                         : (c.clusters ? static_cast<void*>(&cluster_features) : nullptr),
        VK_TRUE};
    VkPhysicalDeviceAccelerationStructureFeaturesKHR as_features{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ACCELERATION_STRUCTURE_FEATURES_KHR, &ray_query};
    as_features.accelerationStructure = VK_TRUE;
    VkPhysicalDeviceVulkan12Features v12{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES,
                                         &as_features};
    v12.bufferDeviceAddress = VK_TRUE;
    const float priority = 1.f;
    VkDeviceQueueCreateInfo qci{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
    qci.queueFamilyIndex = c.family;
    qci.queueCount = 1;
    qci.pQueuePriorities = &priority;
    VkDeviceCreateInfo dci{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO, &v12};
    dci.queueCreateInfoCount = 1;
    dci.pQueueCreateInfos = &qci;
    dci.enabledExtensionCount = uint32_t(enabled.size());
    dci.ppEnabledExtensionNames = enabled.data();
    CHECK(vkCreateDevice(c.physical, &dci, nullptr, &c.device));
    vkGetDeviceQueue(c.device, c.family, 0, &c.queue);
#define LOAD(member, name) c.fn.member = (PFN_##name)vkGetDeviceProcAddr(c.device, #name)
    LOAD(build_sizes, vkGetAccelerationStructureBuildSizesKHR);
    LOAD(create_as, vkCreateAccelerationStructureKHR);
    LOAD(destroy_as, vkDestroyAccelerationStructureKHR);
    LOAD(cmd_build, vkCmdBuildAccelerationStructuresKHR);
    LOAD(as_address, vkGetAccelerationStructureDeviceAddressKHR);
    LOAD(cluster_sizes, vkGetClusterAccelerationStructureBuildSizesNV);
    LOAD(cmd_build_clusters, vkCmdBuildClusterAccelerationStructureIndirectNV);
#undef LOAD
    if (c.clusters && (!c.fn.cluster_sizes || !c.fn.cmd_build_clusters))
        fail("vkGetDeviceProcAddr of the cluster entry points", VK_ERROR_EXTENSION_NOT_PRESENT);
}

Buffer create_buffer(const Context& c, VkDeviceSize size, VkBufferUsageFlags usage, bool host) {
    Buffer b;
    VkBufferCreateInfo bci{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
    bci.size = size;
    bci.usage = usage | VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;
    CHECK(vkCreateBuffer(c.device, &bci, nullptr, &b.buffer));
    VkMemoryRequirements req;
    vkGetBufferMemoryRequirements(c.device, b.buffer, &req);
    const VkMemoryPropertyFlags want =
        host ? VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT
             : VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT;
    uint32_t type = 0;
    while (type < c.memory.memoryTypeCount &&
           (!(req.memoryTypeBits & (1u << type)) ||
            (c.memory.memoryTypes[type].propertyFlags & want) != want))
        ++type;
    if (type == c.memory.memoryTypeCount) fail("finding a memory type", VK_ERROR_UNKNOWN);
    VkMemoryAllocateFlagsInfo flags{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_FLAGS_INFO, nullptr,
                                    VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT, 0};
    VkMemoryAllocateInfo mai{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, &flags, req.size, type};
    CHECK(vkAllocateMemory(c.device, &mai, nullptr, &b.memory));
    CHECK(vkBindBufferMemory(c.device, b.buffer, b.memory, 0));
    if (host) CHECK(vkMapMemory(c.device, b.memory, 0, VK_WHOLE_SIZE, 0, &b.mapped));
    VkBufferDeviceAddressInfo info{VK_STRUCTURE_TYPE_BUFFER_DEVICE_ADDRESS_INFO, nullptr, b.buffer};
    b.address = vkGetBufferDeviceAddress(c.device, &info);
    return b;
}

void destroy_buffer(const Context& c, Buffer& b) {
    vkDestroyBuffer(c.device, b.buffer, nullptr);
    vkFreeMemory(c.device, b.memory, nullptr);
}

// The geometry of mesh `m`'s BLAS: its vertices at `vertices` (a device-local buffer).
VkAccelerationStructureGeometryKHR triangle_geometry(VkDeviceAddress vertices,
                                                     uint32_t vertex_count) {
    VkAccelerationStructureGeometryKHR g{VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    g.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    g.flags = VK_GEOMETRY_OPAQUE_BIT_KHR;
    auto& t = g.geometry.triangles;
    t.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_TRIANGLES_DATA_KHR;
    t.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    t.vertexData.deviceAddress = vertices;
    t.vertexStride = sizeof(Vec3);
    t.maxVertex = vertex_count - 1;
    t.indexType = VK_INDEX_TYPE_NONE_KHR;
    return g;
}

VkAccelerationStructureGeometryKHR instance_geometry(VkDeviceAddress instances) {
    VkAccelerationStructureGeometryKHR g{VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    g.geometryType = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    g.flags = VK_GEOMETRY_OPAQUE_BIT_KHR;
    g.geometry.instances.sType =
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_INSTANCES_DATA_KHR;
    g.geometry.instances.data.deviceAddress = instances;
    return g;
}

VkAccelerationStructureBuildGeometryInfoKHR build_info(
    VkAccelerationStructureTypeKHR type, const VkAccelerationStructureGeometryKHR* g) {
    VkAccelerationStructureBuildGeometryInfoKHR info{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR};
    info.type = type;
    info.flags = VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_TRACE_BIT_KHR;
    info.mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR;
    info.geometryCount = 1;
    info.pGeometries = g;
    return info;
}

VkAccelerationStructureBuildSizesInfoKHR sizes_of(
    const Context& c, const VkAccelerationStructureBuildGeometryInfoKHR& info,
    uint32_t primitives) {
    VkAccelerationStructureBuildSizesInfoKHR sizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
    c.fn.build_sizes(c.device, VK_ACCELERATION_STRUCTURE_BUILD_TYPE_DEVICE_KHR, &info, &primitives,
                     &sizes);
    return sizes;
}

VkAccelerationStructureKHR create_structure(const Context& c, const Buffer& storage,
                                            VkDeviceSize offset, VkDeviceSize size,
                                            VkAccelerationStructureTypeKHR type) {
    VkAccelerationStructureCreateInfoKHR ci{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_CREATE_INFO_KHR};
    ci.buffer = storage.buffer;
    ci.offset = offset;
    ci.size = size;
    ci.type = type;
    VkAccelerationStructureKHR as;
    CHECK(c.fn.create_as(c.device, &ci, nullptr, &as));
    return as;
}

// --cluster-blas: each mesh is one cluster (its triangles, indices 0..5 into the mesh's vertices).
// One BUILD_TRIANGLE_CLUSTER command builds both meshes' CLASes (implicit destinations, in the ring
// slot), then one BUILD_CLUSTERS_BOTTOM_LEVEL command a cluster BLAS per mesh over its one CLAS at
// explicit destinations in the pool slot (--implicit: at implicit destinations, the pool slot
// being the build's dstImplicitData). opInput points into the struct: keep it where filled.
struct ClusterCommands {
    VkClusterAccelerationStructureTriangleClusterInputNV triangles{};
    VkClusterAccelerationStructureClustersBottomLevelInputNV bottom_level{};
    VkClusterAccelerationStructureCommandsInfoNV clas{}, blas{};
};

void fill_cluster_inputs(uint32_t vertices_per_mesh, bool implicit_blas, ClusterCommands& k) {
    k.triangles.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    k.triangles.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    k.triangles.maxClusterUniqueGeometryCount = 1;  // geometry index 0 everywhere
    k.triangles.maxClusterTriangleCount = vertices_per_mesh / 3;
    k.triangles.maxClusterVertexCount = vertices_per_mesh;
    k.triangles.maxTotalTriangleCount = kMeshCount * vertices_per_mesh / 3;
    k.triangles.maxTotalVertexCount = kMeshCount * vertices_per_mesh;
    k.clas.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    k.clas.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    k.clas.input.maxAccelerationStructureCount = kMeshCount;
    k.clas.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    k.clas.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    k.clas.input.opInput.pTriangleClusters = &k.triangles;
    k.bottom_level.sType =
        VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV;
    k.bottom_level.maxTotalClusterCount = kMeshCount;
    k.bottom_level.maxClusterCountPerAccelerationStructure = 1;
    k.blas.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    k.blas.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    k.blas.input.maxAccelerationStructureCount = kMeshCount;
    k.blas.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV;
    k.blas.input.opMode = implicit_blas
                              ? VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV
                              : VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    k.blas.input.opInput.pClustersBottomLevel = &k.bottom_level;
}

VkAccelerationStructureBuildSizesInfoKHR cluster_sizes_of(
    const Context& c, const VkClusterAccelerationStructureInputInfoNV& input) {
    VkAccelerationStructureBuildSizesInfoKHR sizes{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
    c.fn.cluster_sizes(c.device, &input, &sizes);
    return sizes;
}

// --cluster-blas: what the host writes for the two cluster commands, one buffer per ring slot.
constexpr uint32_t kClusterIndices = 6;  // a mesh's triangle list: 2 triangles
struct ClusterInputs {
    std::array<VkClusterAccelerationStructureBuildTriangleClusterInfoNV, kMeshCount> clusters;
    uint32_t counts[2];  // srcInfosCount of the CLAS build, then of the BLAS build
    std::array<VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV, kMeshCount> blases;
    // The frame's pool slot; --implicit: where the build put each BLAS (it writes them).
    std::array<VkDeviceAddress, kMeshCount> blas_destinations;
    std::array<uint32_t, kMeshCount> blas_sizes;  // --implicit: written by the build too
    std::array<uint32_t, kClusterIndices> indices;
};

// Where every object of a frame lives: byte offsets and sizes fixed at start-up.
struct Layout {
    uint32_t vertices_per_mesh = 0;
    VkDeviceSize vertex_bytes = 0;  // all meshes, mesh m at m * per-mesh bytes
    // In a pool slot's storage buffer; --implicit: blas_size is the whole dstImplicitData region.
    VkDeviceSize blas_size = 0, blas_stride = 0;
    VkDeviceSize tlas_size = 0;
    VkDeviceSize scratch_stride = 0;  // one scratch region per BLAS, then the TLAS's
    VkDeviceSize pixel_bytes = 0;
    VkDeviceSize clas_bytes = 0;  // --cluster-blas: the CLAS build's implicit destination
};

Layout plan_layout(const Context& c, uint32_t width, uint32_t height) {
    Layout l;
    l.vertices_per_mesh = uint32_t(mesh_vertices(0, 0).size());
    l.vertex_bytes = VkDeviceSize(kMeshCount) * l.vertices_per_mesh * sizeof(Vec3);
    const VkAccelerationStructureGeometryKHR tri = triangle_geometry(0, l.vertices_per_mesh);
    const auto blas = sizes_of(c, build_info(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, &tri),
                               l.vertices_per_mesh / 3);
    const VkAccelerationStructureGeometryKHR inst = instance_geometry(0);
    const auto tlas =
        sizes_of(c, build_info(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR, &inst), kMeshCount);
    l.blas_size = blas.accelerationStructureSize;
    l.blas_stride = align_up(blas.accelerationStructureSize, kAlignment);
    l.tlas_size = tlas.accelerationStructureSize;
    l.scratch_stride =
        align_up(std::max(blas.buildScratchSize, tlas.buildScratchSize), c.scratch_alignment);
    l.pixel_bytes = VkDeviceSize(width) * height * sizeof(uint32_t);
    if (c.clusters) {
        if (l.vertices_per_mesh != kClusterIndices)
            fail("planning one cluster per mesh", VK_ERROR_UNKNOWN);
        ClusterCommands k;
        fill_cluster_inputs(l.vertices_per_mesh, c.implicit_blas, k);
        const auto clas = cluster_sizes_of(c, k.clas.input);
        const auto cluster_blas = cluster_sizes_of(c, k.blas.input);
        l.clas_bytes = clas.accelerationStructureSize;
        // Each explicit destination's room; --implicit: the region that holds all of them.
        l.blas_size = cluster_blas.accelerationStructureSize;
        l.blas_stride = align_up(l.blas_size, c.cluster_alignment);
        l.scratch_stride = align_up(std::max({clas.buildScratchSize, cluster_blas.buildScratchSize,
                                              tlas.buildScratchSize}),
                                    c.scratch_alignment);
    }
    return l;
}

// One slot of the BLAS pool: a BLAS per mesh in one storage buffer.
struct PoolSlot {
    Buffer storage;
    std::array<VkAccelerationStructureKHR, kMeshCount> blas{};
    std::array<VkDeviceAddress, kMeshCount> address{};
};

// One frame in flight: everything but the BLASes, reused once its fence says the frame is done.
struct RingSlot {
    Buffer staging, vertices, instances, scratch, tlas_storage, pixels;
    Buffer cluster_inputs, clas, clas_outputs;  // --cluster-blas only
    VkAccelerationStructureKHR tlas = VK_NULL_HANDLE;
    VkCommandBuffer cb = VK_NULL_HANDLE;
    VkFence fence = VK_NULL_HANDLE;
    VkDescriptorSet set = VK_NULL_HANDLE;
};

// --cluster-blas: the slot's cluster BLASes are explicit destinations in its storage buffer
// (--implicit: the buffer is the build's dstImplicitData, and the addresses are the build's).
PoolSlot create_cluster_pool_slot(const Context& c, const Layout& l) {
    PoolSlot p;
    const VkDeviceSize bytes = c.implicit_blas ? l.blas_size : l.blas_stride * kMeshCount;
    p.storage = create_buffer(c, bytes + c.cluster_alignment,
                              VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR, false);
    for (uint32_t m = 0; m < kMeshCount && !c.implicit_blas; ++m)
        p.address[m] = align_up(p.storage.address, c.cluster_alignment) + m * l.blas_stride;
    return p;
}

PoolSlot create_pool_slot(const Context& c, const Layout& l) {
    if (c.clusters) return create_cluster_pool_slot(c, l);
    PoolSlot p;
    p.storage = create_buffer(c, l.blas_stride * kMeshCount,
                              VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR, false);
    for (uint32_t m = 0; m < kMeshCount; ++m) {
        p.blas[m] = create_structure(c, p.storage, m * l.blas_stride, l.blas_size,
                                     VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR);
        VkAccelerationStructureDeviceAddressInfoKHR info{
            VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_DEVICE_ADDRESS_INFO_KHR, nullptr, p.blas[m]};
        p.address[m] = c.fn.as_address(c.device, &info);
    }
    return p;
}

// --cluster-blas: the ring slot's CLAS storage, the addresses and sizes the CLAS build writes,
// and the host's inputs of both cluster commands; all but the frame's BLAS destinations fixed here.
void create_cluster_buffers(const Context& c, const Layout& l, RingSlot& r) {
    const VkBufferUsageFlags storage = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
    const VkBufferUsageFlags build_input =
        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    r.clas = create_buffer(c, l.clas_bytes + c.cluster_alignment, storage, false);
    r.clas_outputs = create_buffer(c, kMeshCount * (8 + 4), storage | build_input, false);
    // Storage too: the BLAS build's dstAddressesArray is in it (VUID ...-12307); --implicit: the
    // frame copies the addresses the build wrote there into its instances.
    r.cluster_inputs = create_buffer(c, sizeof(ClusterInputs),
                                     storage | build_input |
                                         (c.implicit_blas ? VK_BUFFER_USAGE_TRANSFER_SRC_BIT : 0),
                                     true);
    ClusterInputs in{};
    const VkDeviceAddress inputs = r.cluster_inputs.address;
    for (uint32_t m = 0; m < kMeshCount; ++m) {
        auto& cluster = in.clusters[m];
        cluster.clusterID = m;
        cluster.triangleCount = l.vertices_per_mesh / 3;
        cluster.vertexCount = l.vertices_per_mesh;
        cluster.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
        cluster.baseGeometryIndexAndGeometryFlags.geometryFlags =
            VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_OPAQUE_BIT_NV;
        cluster.indexBuffer = inputs + offsetof(ClusterInputs, indices);
        cluster.vertexBuffer = r.vertices.address + m * l.vertices_per_mesh * sizeof(Vec3);
        // Mesh m's BLAS references the one CLAS address the CLAS build writes for cluster m.
        in.blases[m] = {1, 8, r.clas_outputs.address + 8 * m};
        in.blas_sizes[m] = uint32_t(l.blas_size);
    }
    in.counts[0] = in.counts[1] = kMeshCount;
    for (uint32_t i = 0; i < kClusterIndices; ++i) in.indices[i] = i;
    std::memcpy(r.cluster_inputs.mapped, &in, sizeof in);
}

RingSlot create_ring_slot(const Context& c, const Layout& l, VkCommandPool pool,
                          VkDescriptorPool descriptors, VkDescriptorSetLayout set_layout) {
    RingSlot r;
    const VkBufferUsageFlags build_input =
        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    r.staging = create_buffer(c, l.vertex_bytes, VK_BUFFER_USAGE_TRANSFER_SRC_BIT, true);
    r.vertices =
        create_buffer(c, l.vertex_bytes, VK_BUFFER_USAGE_TRANSFER_DST_BIT | build_input, false);
    r.instances =
        create_buffer(c, kMeshCount * sizeof(VkAccelerationStructureInstanceKHR),
                      build_input | (c.implicit_blas ? VK_BUFFER_USAGE_TRANSFER_DST_BIT : 0), true);
    r.scratch = create_buffer(c, l.scratch_stride * (kMeshCount + 1) + c.scratch_alignment,
                              VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, false);
    r.tlas_storage = create_buffer(c, l.tlas_size,
                                   VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR, false);
    r.pixels = create_buffer(c, l.pixel_bytes, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, true);
    r.tlas = create_structure(c, r.tlas_storage, 0, l.tlas_size,
                              VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR);
    if (c.clusters) create_cluster_buffers(c, l, r);
    VkCommandBufferAllocateInfo cai{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, nullptr, pool,
                                    VK_COMMAND_BUFFER_LEVEL_PRIMARY, 1};
    CHECK(vkAllocateCommandBuffers(c.device, &cai, &r.cb));
    VkFenceCreateInfo fci{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
    CHECK(vkCreateFence(c.device, &fci, nullptr, &r.fence));
    VkDescriptorSetAllocateInfo dai{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO, nullptr,
                                    descriptors, 1, &set_layout};
    CHECK(vkAllocateDescriptorSets(c.device, &dai, &r.set));
    VkWriteDescriptorSetAccelerationStructureKHR as_write{
        VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET_ACCELERATION_STRUCTURE_KHR, nullptr, 1, &r.tlas};
    VkDescriptorBufferInfo pixels{r.pixels.buffer, 0, l.pixel_bytes};
    VkWriteDescriptorSet writes[2] = {{VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET},
                                      {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET}};
    writes[0].pNext = &as_write;
    writes[0].dstSet = r.set;
    writes[0].dstBinding = 0;
    writes[0].descriptorCount = 1;
    writes[0].descriptorType = VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR;
    writes[1].dstSet = r.set;
    writes[1].dstBinding = 1;
    writes[1].descriptorCount = 1;
    writes[1].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    writes[1].pBufferInfo = &pixels;
    vkUpdateDescriptorSets(c.device, 2, writes, 0, nullptr);
    return r;
}

struct Pipeline {
    VkDescriptorSetLayout set_layout = VK_NULL_HANDLE;
    VkPipelineLayout layout = VK_NULL_HANDLE;
    VkPipeline pipeline = VK_NULL_HANDLE;
};

Pipeline create_pipeline(const Context& c) {
    Pipeline p;
    VkDescriptorSetLayoutBinding bindings[2] = {{0, VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR,
                                                 1, VK_SHADER_STAGE_COMPUTE_BIT, nullptr},
                                                {1, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1,
                                                 VK_SHADER_STAGE_COMPUTE_BIT, nullptr}};
    VkDescriptorSetLayoutCreateInfo dl{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
    dl.bindingCount = 2;
    dl.pBindings = bindings;
    CHECK(vkCreateDescriptorSetLayout(c.device, &dl, nullptr, &p.set_layout));
    VkPushConstantRange push{VK_SHADER_STAGE_COMPUTE_BIT, 0, 2 * sizeof(uint32_t)};
    VkPipelineLayoutCreateInfo pl{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
    pl.setLayoutCount = 1;
    pl.pSetLayouts = &p.set_layout;
    pl.pushConstantRangeCount = 1;
    pl.pPushConstantRanges = &push;
    CHECK(vkCreatePipelineLayout(c.device, &pl, nullptr, &p.layout));
    VkShaderModuleCreateInfo sm{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
    sm.codeSize = sizeof(kTracePixelsSpirv);
    sm.pCode = kTracePixelsSpirv;
    VkShaderModule module;
    CHECK(vkCreateShaderModule(c.device, &sm, nullptr, &module));
    VkComputePipelineCreateInfo cp{VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO};
    cp.stage = {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO,
                nullptr,
                0,
                VK_SHADER_STAGE_COMPUTE_BIT,
                module,
                "main",
                nullptr};
    cp.layout = p.layout;
    CHECK(vkCreateComputePipelines(c.device, VK_NULL_HANDLE, 1, &cp, nullptr, &p.pipeline));
    vkDestroyShaderModule(c.device, module, nullptr);
    return p;
}

void memory_barrier(VkCommandBuffer cb, VkPipelineStageFlags src_stage, VkAccessFlags src,
                    VkPipelineStageFlags dst_stage, VkAccessFlags dst) {
    VkMemoryBarrier b{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, src, dst};
    vkCmdPipelineBarrier(cb, src_stage, dst_stage, 0, 1, &b, 0, nullptr, 0, nullptr);
}

struct Options {
    uint32_t frames = 8, width = 96, height = 64;
    uint32_t build_frames = UINT32_MAX;  // frames from this one on trace what earlier ones built
    bool single_buffered_pool = false, skip_vertex_barrier = false;
    bool cluster_blas = false;   // BLASes as cluster BLASes (VK_NV_cluster_acceleration_structure)
    bool implicit_blas = false;  // --implicit: those at implicit destinations
    std::string image;
};

void record_dispatch(const Pipeline& pipe, const Options& o, const RingSlot& r) {
    VkCommandBuffer cb = r.cb;
    vkCmdBindPipeline(cb, VK_PIPELINE_BIND_POINT_COMPUTE, pipe.pipeline);
    vkCmdBindDescriptorSets(cb, VK_PIPELINE_BIND_POINT_COMPUTE, pipe.layout, 0, 1, &r.set, 0,
                            nullptr);
    const uint32_t size[2] = {o.width, o.height};
    vkCmdPushConstants(cb, pipe.layout, VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(size), size);
    vkCmdDispatch(cb, (o.width + 7) / 8, (o.height + 7) / 8, 1);
    memory_barrier(cb, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_WRITE_BIT,
                   VK_PIPELINE_STAGE_HOST_BIT, VK_ACCESS_HOST_READ_BIT);
}

// --build-frames: a later frame only traces the ring slot's TLAS (over the BLASes) that an
// earlier frame built and that nothing has changed since.
void record_trace_only(const Pipeline& pipe, const Options& o, RingSlot& r) {
    CHECK(vkResetCommandBuffer(r.cb, 0));
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    CHECK(vkBeginCommandBuffer(r.cb, &begin));
    record_dispatch(pipe, o, r);
    CHECK(vkEndCommandBuffer(r.cb));
}

// One vkCmdBuildAccelerationStructuresKHR: a BLAS per mesh into the pool slot.
void record_khr_blas_builds(const Context& c, const Layout& l, const RingSlot& r, const PoolSlot& p,
                            VkDeviceAddress scratch) {
    std::array<VkAccelerationStructureGeometryKHR, kMeshCount> geometry;
    std::array<VkAccelerationStructureBuildGeometryInfoKHR, kMeshCount> infos;
    std::array<VkAccelerationStructureBuildRangeInfoKHR, kMeshCount> ranges;
    std::array<const VkAccelerationStructureBuildRangeInfoKHR*, kMeshCount> range_pointers;
    for (uint32_t m = 0; m < kMeshCount; ++m) {
        geometry[m] = triangle_geometry(r.vertices.address + m * l.vertices_per_mesh * sizeof(Vec3),
                                        l.vertices_per_mesh);
        infos[m] = build_info(VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR, &geometry[m]);
        infos[m].dstAccelerationStructure = p.blas[m];
        infos[m].scratchData.deviceAddress = scratch + m * l.scratch_stride;
        ranges[m] = {l.vertices_per_mesh / 3, 0, 0, 0};
        range_pointers[m] = &ranges[m];
    }
    c.fn.cmd_build(r.cb, kMeshCount, infos.data(), range_pointers.data());
}

// --implicit: the instances take the addresses the cluster BLAS build wrote to its
// dstAddressesArray, copied on the GPU between that build and the TLAS build (as an application
// whose BLAS addresses are known only to the GPU does).
void record_implicit_references(const RingSlot& r) {
    memory_barrier(r.cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                   VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR, VK_PIPELINE_STAGE_TRANSFER_BIT,
                   VK_ACCESS_TRANSFER_READ_BIT);
    std::array<VkBufferCopy, kMeshCount> copies;
    for (uint32_t m = 0; m < kMeshCount; ++m)
        copies[m] = {offsetof(ClusterInputs, blas_destinations) + m * sizeof(VkDeviceAddress),
                     m * sizeof(VkAccelerationStructureInstanceKHR) +
                         offsetof(VkAccelerationStructureInstanceKHR,
                                  accelerationStructureReference),
                     sizeof(VkDeviceAddress)};
    vkCmdCopyBuffer(r.cb, r.cluster_inputs.buffer, r.instances.buffer, kMeshCount, copies.data());
    memory_barrier(r.cb, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                   VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                   VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR);
}

// --cluster-blas: the CLASes of both meshes (ring slot), a barrier, then one cluster BLAS per mesh
// at the pool slot's addresses (ClusterCommands), or --implicit packed into the pool slot.
void record_cluster_blas_builds(const Context& c, const Layout& l, const RingSlot& r,
                                const PoolSlot& p, VkDeviceAddress scratch) {
    constexpr VkDeviceSize kInfo = sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);
    constexpr VkDeviceSize kBlasInfo =
        sizeof(VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV);
    ClusterCommands k;
    fill_cluster_inputs(l.vertices_per_mesh, c.implicit_blas, k);
    const VkDeviceAddress in = r.cluster_inputs.address, out = r.clas_outputs.address;
    k.clas.dstImplicitData = align_up(r.clas.address, c.cluster_alignment);
    k.clas.scratchData = scratch;
    k.clas.dstAddressesArray = {out, 8, 8 * kMeshCount};
    k.clas.dstSizesArray = {out + 8 * kMeshCount, 4, 4 * kMeshCount};
    k.clas.srcInfosArray = {in + offsetof(ClusterInputs, clusters), kInfo, kInfo * kMeshCount};
    k.clas.srcInfosCount = in + offsetof(ClusterInputs, counts);
    c.fn.cmd_build_clusters(r.cb, &k.clas);
    // The BLAS build reads the CLASes and the CLAS addresses the first build wrote.
    memory_barrier(r.cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                   VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                   VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                   VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR | VK_ACCESS_SHADER_READ_BIT);
    k.blas.scratchData = scratch + l.scratch_stride;
    k.blas.dstAddressesArray = {in + offsetof(ClusterInputs, blas_destinations), 8, 8 * kMeshCount};
    k.blas.dstSizesArray = {in + offsetof(ClusterInputs, blas_sizes), 4, 4 * kMeshCount};
    k.blas.srcInfosArray = {in + offsetof(ClusterInputs, blases), kBlasInfo,
                            kBlasInfo * kMeshCount};
    k.blas.srcInfosCount = in + offsetof(ClusterInputs, counts) + sizeof(uint32_t);
    if (c.implicit_blas) k.blas.dstImplicitData = align_up(p.storage.address, c.cluster_alignment);
    c.fn.cmd_build_clusters(r.cb, &k.blas);
    if (c.implicit_blas) record_implicit_references(r);
}

// The frame's host work (vertices, instances) and its one command buffer.
void record_frame(const Context& c, const Layout& l, const Pipeline& pipe, const Options& o,
                  uint64_t frame, RingSlot& r, const PoolSlot& p) {
    if (frame >= o.build_frames) return record_trace_only(pipe, o, r);
    for (uint32_t m = 0; m < kMeshCount; ++m) {
        const std::vector<Vec3> v = mesh_vertices(m, frame);
        std::memcpy((char*)r.staging.mapped + m * l.vertices_per_mesh * sizeof(Vec3), v.data(),
                    v.size() * sizeof(Vec3));
        VkAccelerationStructureInstanceKHR instance{};
        instance_transform(m, &instance.transform.matrix[0][0]);
        instance.instanceCustomIndex = m;
        instance.mask = 0xff;
        instance.accelerationStructureReference = p.address[m];
        std::memcpy((char*)r.instances.mapped + m * sizeof(instance), &instance, sizeof(instance));
        if (c.clusters && !c.implicit_blas)  // the BLAS build's explicit destinations: the pool
            std::memcpy((char*)r.cluster_inputs.mapped +
                            offsetof(ClusterInputs, blas_destinations) +
                            m * sizeof(VkDeviceAddress),
                        &p.address[m], sizeof(VkDeviceAddress));
    }
    VkCommandBuffer cb = r.cb;
    CHECK(vkResetCommandBuffer(cb, 0));
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    CHECK(vkBeginCommandBuffer(cb, &begin));
    const VkBufferCopy copy{0, 0, l.vertex_bytes};
    vkCmdCopyBuffer(cb, r.staging.buffer, r.vertices.buffer, 1, &copy);
    if (!o.skip_vertex_barrier)  // Vulkan-ValidationLayers #7372 is this barrier left out
        memory_barrier(cb, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                       VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_SHADER_READ_BIT);
    const VkDeviceAddress scratch = align_up(r.scratch.address, c.scratch_alignment);
    if (c.clusters)
        record_cluster_blas_builds(c, l, r, p, scratch);
    else
        record_khr_blas_builds(c, l, r, p, scratch);
    memory_barrier(cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                   VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                   VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                   VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR);
    const VkAccelerationStructureGeometryKHR top = instance_geometry(r.instances.address);
    VkAccelerationStructureBuildGeometryInfoKHR top_info =
        build_info(VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR, &top);
    top_info.dstAccelerationStructure = r.tlas;
    top_info.scratchData.deviceAddress = scratch + kMeshCount * l.scratch_stride;
    const VkAccelerationStructureBuildRangeInfoKHR top_range{kMeshCount, 0, 0, 0};
    const VkAccelerationStructureBuildRangeInfoKHR* top_range_pointer = &top_range;
    c.fn.cmd_build(cb, 1, &top_info, &top_range_pointer);
    memory_barrier(cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                   VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                   VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                   VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR);
    record_dispatch(pipe, o, r);
    CHECK(vkEndCommandBuffer(cb));
}

void submit_frame(const Context& c, uint64_t frame, RingSlot& r) {
    VkFrameBoundaryEXT boundary{VK_STRUCTURE_TYPE_FRAME_BOUNDARY_EXT};
    boundary.flags = VK_FRAME_BOUNDARY_FRAME_END_BIT_EXT;
    boundary.frameID = frame;
    boundary.bufferCount = 1;
    boundary.pBuffers = &r.pixels.buffer;  // the frame's result
    VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO, c.frame_boundary ? &boundary : nullptr};
    submit.commandBufferCount = 1;
    submit.pCommandBuffers = &r.cb;
    CHECK(vkQueueSubmit(c.queue, 1, &submit, r.fence));
}

int run(const Options& o) {
    Context c;
    c.clusters = o.cluster_blas;
    c.implicit_blas = o.implicit_blas;
    create_context(c);
    const Layout l = plan_layout(c, o.width, o.height);
    const Pipeline pipe = create_pipeline(c);
    VkCommandPoolCreateInfo cpi{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO, nullptr,
                                VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT, c.family};
    VkCommandPool command_pool;
    CHECK(vkCreateCommandPool(c.device, &cpi, nullptr, &command_pool));
    VkDescriptorPoolSize pool_sizes[2] = {{VK_DESCRIPTOR_TYPE_ACCELERATION_STRUCTURE_KHR,
                                           kRingSlots},
                                          {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, kRingSlots}};
    VkDescriptorPoolCreateInfo dpi{
        VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO, nullptr, 0, kRingSlots, 2, pool_sizes};
    VkDescriptorPool descriptor_pool;
    CHECK(vkCreateDescriptorPool(c.device, &dpi, nullptr, &descriptor_pool));
    // The BLAS pool: one slot per frame in flight, or one shared slot (the dxvk-remix bug).
    std::vector<PoolSlot> pool(o.single_buffered_pool ? 1 : kRingSlots);
    for (PoolSlot& p : pool) p = create_pool_slot(c, l);
    std::vector<RingSlot> ring(kRingSlots);
    for (RingSlot& r : ring)
        r = create_ring_slot(c, l, command_pool, descriptor_pool, pipe.set_layout);

    const auto loop_start = std::chrono::steady_clock::now();
    for (uint64_t frame = 0; frame < o.frames; ++frame) {
        RingSlot& r = ring[frame % kRingSlots];
        // The ring slot's fence: frame - kRingSlots is done with this slot. With a single pool
        // slot nothing waits for frame - 1, whose rays may still read the BLASes rebuilt below.
        if (frame >= kRingSlots) {
            CHECK(vkWaitForFences(c.device, 1, &r.fence, VK_TRUE, UINT64_MAX));
            CHECK(vkResetFences(c.device, 1, &r.fence));
        }
        record_frame(c, l, pipe, o, frame, r, pool[frame % pool.size()]);
        submit_frame(c, frame, r);
    }
    CHECK(vkDeviceWaitIdle(c.device));
    const std::chrono::duration<double, std::milli> loop =
        std::chrono::steady_clock::now() - loop_start;
    const RingSlot& last = ring[(o.frames - 1) % kRingSlots];
    std::vector<uint32_t> pixels(size_t(o.width) * o.height);
    std::memcpy(pixels.data(), last.pixels.mapped, l.pixel_bytes);
    std::printf("frames %u pool_slots %zu blas %s frame_boundary %s checksum %016llx\n", o.frames,
                pool.size(),
                c.implicit_blas ? "cluster-implicit" : (c.clusters ? "cluster" : "khr"),
                c.frame_boundary ? "on" : "off", (unsigned long long)image_checksum(pixels));
    std::printf("loop_ms=%.3f\n", loop.count());  // the frames, recorded to done (benches)
    int status = 0;
    std::string error;
    if (!o.image.empty() && !write_ppm(o.image, pixels, o.width, o.height, error)) {
        std::fprintf(stderr, "rt_frame_loop: %s\n", error.c_str());
        status = 2;
    }
    for (RingSlot& r : ring) {
        c.fn.destroy_as(c.device, r.tlas, nullptr);
        for (Buffer* b : {&r.staging, &r.vertices, &r.instances, &r.scratch, &r.tlas_storage,
                          &r.pixels, &r.cluster_inputs, &r.clas, &r.clas_outputs})
            destroy_buffer(c, *b);
        vkDestroyFence(c.device, r.fence, nullptr);
    }
    for (PoolSlot& p : pool) {
        for (VkAccelerationStructureKHR as : p.blas)  // none with --cluster-blas
            if (as) c.fn.destroy_as(c.device, as, nullptr);
        destroy_buffer(c, p.storage);
    }
    vkDestroyDescriptorPool(c.device, descriptor_pool, nullptr);
    vkDestroyCommandPool(c.device, command_pool, nullptr);
    vkDestroyPipeline(c.device, pipe.pipeline, nullptr);
    vkDestroyPipelineLayout(c.device, pipe.layout, nullptr);
    vkDestroyDescriptorSetLayout(c.device, pipe.set_layout, nullptr);
    vkDestroyDevice(c.device, nullptr);
    vkDestroyInstance(c.instance, nullptr);
    return status;
}

}  // namespace
}  // namespace rt_frame_loop

int main(int argc, char** argv) {
    rt_frame_loop::Options o;
    CLI::App app{
        "rt_frame_loop: a headless ray-traced frame loop on KHR acceleration structures "
        "(examples/rt_frame_loop/README.md). Exit codes: 0 done, 1 usage, 2 failure, 3 no "
        "device with VK_KHR_acceleration_structure and VK_KHR_ray_query."};
    app.add_option("--frames", o.frames, "frames to render (each marked with VkFrameBoundaryEXT)")
        ->check(CLI::Range(1u, 1000000u));
    app.add_option("--width", o.width, "image width")->check(CLI::Range(1u, 4096u));
    app.add_option("--height", o.height, "image height")->check(CLI::Range(1u, 4096u));
    app.add_option("--image", o.image, "write the last frame's image here (binary PPM)");
    app.add_flag("--single-buffered-pool", o.single_buffered_pool,
                 "one BLAS pool slot, rebuilt each frame without waiting for the previous frame's "
                 "rays (the dxvk-remix bug)");
    app.add_flag("--cluster-blas", o.cluster_blas,
                 "build each mesh's BLAS as a cluster BLAS (VK_NV_cluster_acceleration_structure: "
                 "a CLAS per mesh, then cluster BLASes at explicit destinations in the pool); "
                 "needs the extension, which the clastrace capture layer serves (and, on lavapipe "
                 "25, makes traceable): run it under `clastrace capture`");
    app.add_flag("--implicit", o.implicit_blas,
                 "with --cluster-blas: the cluster BLASes at implicit destinations (the pool slot "
                 "is the build's dstImplicitData; a GPU copy puts the addresses the build wrote "
                 "into the TLAS's instances)")
        ->needs("--cluster-blas");
    app.add_flag("--skip-vertex-barrier", o.skip_vertex_barrier,
                 "no barrier between the vertex copy and the BLAS builds "
                 "(Vulkan-ValidationLayers #7372)");
    app.add_option("--build-frames", o.build_frames,
                   "build the BLASes and TLASes only in frames 0..N-1 (N >= 2, the ring slots); "
                   "later frames trace what "
                   "their ring slot's earlier frame built (default: build every frame)")
        ->check(CLI::Range(2u, UINT32_MAX));
    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        const int code = app.exit(e);
        return code == 0 ? 0 : 1;
    }
    return rt_frame_loop::run(o);
}
