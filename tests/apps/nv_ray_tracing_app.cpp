// SPDX-License-Identifier: Apache-2.0
// A small VK_NV_ray_tracing program for capturing the two older acceleration-structure
// commands on a real driver (issue 8; traces/samples/h100_nv_ray_tracing.clt was made with it):
//
//   submission 0: vkCmdBuildAccelerationStructureNV x3: a triangle bottom level (two geometries:
//                 a 7x7-vertex height field with uint32 indices, 16-byte vertex stride and a 3x4
//                 transform; a uint16-indexed tetrahedron), an AABB bottom level (8 boxes, 32-byte
//                 stride), and a top level from 5 instance records (transforms, custom indices,
//                 masks, SBT offsets, flags), all ALLOW_UPDATE;
//   submission 1: the same three as updates (refit) after the host moved vertices, boxes and
//                 instance transforms;
//   then it traces 4096 rays (a grid aimed at the scene plus seeded random ones) against the top
//   level with the shared NV ray-tracing pipeline and prints a summary of the hits;
//   submissions 2-4 (VK_KHR_acceleration_structure): a KHR bottom level built with
//                 vkCmdBuildAccelerationStructuresKHR, serialized with
//                 vkCmdCopyAccelerationStructureToMemoryKHR, and deserialized into a new KHR
//                 structure with vkCmdCopyMemoryToAccelerationStructureKHR.
//
// Without VK_NV_ray_tracing (lavapipe) it prints "VK_NV_ray_tracing not available" and exits 0
// (77 with --require). --probe prints the device, driver, extensions and NV ray-tracing limits.
#include "clastrace/capture/nv_ray_tracer.h"
#include "clastrace/common/hex.h"

#include <vulkan/vulkan.h>

#include <cinttypes>
#include <cmath>
#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <limits>
#include <string>
#include <vector>

using clastrace::capture::NvRayHit;
using clastrace::capture::NvTracedRay;
using clastrace::capture::NvTraceScene;

namespace {

#define CHECK(call)                                                                               \
    do {                                                                                          \
        VkResult result_ = (call);                                                                \
        if (result_ != VK_SUCCESS) {                                                              \
            std::fprintf(stderr, "nv_ray_tracing_app: %s failed: VkResult %d (line %d)\n", #call, \
                         int(result_), __LINE__);                                                 \
            std::exit(1);                                                                         \
        }                                                                                         \
    } while (0)

[[noreturn]] void die(const std::string& message) {
    std::fprintf(stderr, "nv_ray_tracing_app: %s\n", message.c_str());
    std::exit(1);
}

bool hasExtension(const std::vector<VkExtensionProperties>& list, const char* name) {
    for (const auto& e : list)
        if (std::strcmp(e.extensionName, name) == 0) return true;
    return false;
}

std::string hex(const uint8_t* bytes, size_t n) { return clastrace::common::hex_bytes({bytes, n}); }

// splitmix64: the rays must be the same on every run and machine.
struct Random {
    uint64_t state;
    uint64_t next() {
        uint64_t z = (state += 0x9E3779B97F4A7C15ull);
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        return z ^ (z >> 31);
    }
    float uniform() { return float(next() >> 40) / float(1 << 24); }  // [0, 1)
};

struct Vulkan {
    VkInstance instance = VK_NULL_HANDLE;
    VkPhysicalDevice physical = VK_NULL_HANDLE;
    VkDevice device = VK_NULL_HANDLE;
    VkQueue queue = VK_NULL_HANDLE;
    uint32_t family = 0;
    VkCommandPool pool = VK_NULL_HANDLE;
    VkPhysicalDeviceMemoryProperties memory{};
    VkPhysicalDeviceRayTracingPropertiesNV rt{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_RAY_TRACING_PROPERTIES_NV};
    bool khr = false;  // VK_KHR_acceleration_structure enabled
    VkPhysicalDeviceAccelerationStructurePropertiesKHR asProperties{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ACCELERATION_STRUCTURE_PROPERTIES_KHR};

    template <typename T>
    T proc(const char* name) {
        auto f = (T)vkGetDeviceProcAddr(device, name);
        if (!f) die(std::string("no ") + name);
        return f;
    }

    uint32_t memoryType(uint32_t bits, VkMemoryPropertyFlags wanted) const {
        for (uint32_t i = 0; i < memory.memoryTypeCount; ++i)
            if ((bits & (1u << i)) && (memory.memoryTypes[i].propertyFlags & wanted) == wanted)
                return i;
        die("no memory type with flags " + std::to_string(wanted));
    }

    VkDeviceMemory allocate(const VkMemoryRequirements& r, VkMemoryPropertyFlags flags,
                            bool deviceAddress) {
        VkMemoryAllocateFlagsInfo flagsInfo{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_FLAGS_INFO};
        flagsInfo.flags = VK_MEMORY_ALLOCATE_DEVICE_ADDRESS_BIT;
        VkMemoryAllocateInfo info{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
        info.pNext = deviceAddress ? &flagsInfo : nullptr;
        info.allocationSize = r.size;
        info.memoryTypeIndex = memoryType(r.memoryTypeBits, flags);
        VkDeviceMemory m;
        CHECK(vkAllocateMemory(device, &info, nullptr, &m));
        return m;
    }

    struct Buffer {
        VkBuffer buffer = VK_NULL_HANDLE;
        VkDeviceMemory memory = VK_NULL_HANDLE;
        void* mapped = nullptr;
        VkDeviceAddress address = 0;
        VkDeviceSize size = 0;
    };
    // Inputs live in host-visible memory: the capture layer reads them through its own mapping.
    Buffer buffer(VkDeviceSize size, VkBufferUsageFlags usage, bool host,
                  bool deviceAddress = false) {
        Buffer b;
        b.size = size;
        VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
        info.size = size;
        info.usage = usage | (deviceAddress ? VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT : 0);
        CHECK(vkCreateBuffer(device, &info, nullptr, &b.buffer));
        VkMemoryRequirements r;
        vkGetBufferMemoryRequirements(device, b.buffer, &r);
        b.memory = allocate(r,
                            host ? VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT |
                                       VK_MEMORY_PROPERTY_HOST_COHERENT_BIT
                                 : VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT,
                            deviceAddress);
        CHECK(vkBindBufferMemory(device, b.buffer, b.memory, 0));
        if (host) CHECK(vkMapMemory(device, b.memory, 0, VK_WHOLE_SIZE, 0, &b.mapped));
        if (deviceAddress) {
            VkBufferDeviceAddressInfo a{VK_STRUCTURE_TYPE_BUFFER_DEVICE_ADDRESS_INFO};
            a.buffer = b.buffer;
            b.address = vkGetBufferDeviceAddress(device, &a);
        }
        return b;
    }
    template <typename T>
    Buffer upload(const std::vector<T>& values, VkBufferUsageFlags usage,
                  bool deviceAddress = false) {
        Buffer b = buffer(values.size() * sizeof(T), usage, true, deviceAddress);
        std::memcpy(b.mapped, values.data(), values.size() * sizeof(T));
        return b;
    }

    void submit(const std::function<void(VkCommandBuffer)>& record) {
        VkCommandBufferAllocateInfo a{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
        a.commandPool = pool;
        a.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
        a.commandBufferCount = 1;
        VkCommandBuffer cb;
        CHECK(vkAllocateCommandBuffers(device, &a, &cb));
        VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
        begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
        CHECK(vkBeginCommandBuffer(cb, &begin));
        record(cb);
        CHECK(vkEndCommandBuffer(cb));
        VkFenceCreateInfo fi{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
        VkFence fence;
        CHECK(vkCreateFence(device, &fi, nullptr, &fence));
        VkSubmitInfo s{VK_STRUCTURE_TYPE_SUBMIT_INFO};
        s.commandBufferCount = 1;
        s.pCommandBuffers = &cb;
        CHECK(vkQueueSubmit(queue, 1, &s, fence));
        CHECK(vkWaitForFences(device, 1, &fence, VK_TRUE, 30'000'000'000ull));
        vkDestroyFence(device, fence, nullptr);
        vkFreeCommandBuffers(device, pool, 1, &cb);
    }
};

void asBarrier(VkCommandBuffer cb) {
    VkMemoryBarrier b{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                      VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_NV |
                          VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_NV,
                      VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_NV |
                          VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_NV};
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_NV,
                         VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_NV, 0, 1, &b, 0,
                         nullptr, 0, nullptr);
}

void printProbe(Vulkan& v, const std::vector<VkExtensionProperties>& extensions) {
    VkPhysicalDeviceDriverProperties driver{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_DRIVER_PROPERTIES};
    VkPhysicalDeviceIDProperties ids{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ID_PROPERTIES, &driver};
    VkPhysicalDeviceRayTracingPropertiesNV rt{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_RAY_TRACING_PROPERTIES_NV, &ids};
    VkPhysicalDeviceProperties2 p{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &rt};
    vkGetPhysicalDeviceProperties2(v.physical, &p);
    const auto& d = p.properties;
    std::printf(
        "probe: device '%s' vendor 0x%04x device 0x%04x api %u.%u.%u driverVersion 0x%08x\n",
        d.deviceName, d.vendorID, d.deviceID, VK_API_VERSION_MAJOR(d.apiVersion),
        VK_API_VERSION_MINOR(d.apiVersion), VK_API_VERSION_PATCH(d.apiVersion), d.driverVersion);
    std::printf("probe: driver '%s' '%s' id %d driverUUID %s deviceUUID %s pipelineCacheUUID %s\n",
                driver.driverName, driver.driverInfo, int(driver.driverID),
                hex(ids.driverUUID, VK_UUID_SIZE).c_str(),
                hex(ids.deviceUUID, VK_UUID_SIZE).c_str(),
                hex(d.pipelineCacheUUID, VK_UUID_SIZE).c_str());
    std::printf(
        "probe: NV ray tracing: handleSize %u maxRecursion %u maxStride %u baseAlignment %u "
        "maxGeometry %" PRIu64 " maxInstance %" PRIu64 " maxTriangle %" PRIu64
        " maxDescriptorSetAS %u\n",
        rt.shaderGroupHandleSize, rt.maxRecursionDepth, rt.maxShaderGroupStride,
        rt.shaderGroupBaseAlignment, rt.maxGeometryCount, rt.maxInstanceCount, rt.maxTriangleCount,
        rt.maxDescriptorSetAccelerationStructures);
    std::printf("probe: %zu device extensions; ray tracing related:", extensions.size());
    for (const auto& e : extensions) {
        const std::string n = e.extensionName;
        if (n.find("ray") != std::string::npos || n.find("acceleration") != std::string::npos ||
            n.find("cluster") != std::string::npos || n.find("deferred") != std::string::npos)
            std::printf(" %s", e.extensionName);
    }
    std::printf("\n");
}

// ---- The scene -------------------------------------------------------------------------------

struct Vertex {
    float x, y, z, pad;  // 16-byte stride: the build must honour vertexStride
};
struct Box {
    float lo[3], hi[3];
    float pad[2];  // 32-byte stride
};

std::vector<Vertex> heightField(float phase) {
    std::vector<Vertex> v;
    for (int j = 0; j < 7; ++j)
        for (int i = 0; i < 7; ++i)
            v.push_back({float(i) - 3.0f,
                         0.4f * std::sin(0.9f * float(i) + phase) * std::cos(0.7f * float(j)),
                         float(j) - 3.0f, 0.0f});
    return v;
}
std::vector<uint32_t> heightFieldIndices() {
    std::vector<uint32_t> idx;
    for (uint32_t j = 0; j < 6; ++j)
        for (uint32_t i = 0; i < 6; ++i) {
            const uint32_t a = j * 7 + i, b = a + 1, c = a + 7, d = c + 1;
            idx.insert(idx.end(), {a, c, b, b, c, d});
        }
    return idx;
}
std::vector<Box> boxes(float lift) {
    std::vector<Box> out;
    for (int k = 0; k < 8; ++k) {
        const float x = float(k % 4) * 1.5f - 2.25f, z = float(k / 4) * 1.5f - 0.75f;
        const float h = 0.3f + 0.1f * float(k) + lift * float(k % 3);
        out.push_back({{x - 0.5f, 0.0f, z - 0.5f}, {x + 0.5f, h, z + 0.5f}, {0, 0}});
    }
    return out;
}

// --extremes: the same structure (two triangle geometries, 8 boxes, 5 instances, build then
// refit) with what numerical extremes look like: a floor triangle 2e4 wide far below, a
// 1e-3 triangle, a degenerate and a NaN (inactive) triangle, a quad split along a shared edge;
// a zero-thickness box, a NaN (inactive) box, a 1e-3 box, two identical boxes, a 2000-wide
// slab; instances mirrored (negative determinant), scaled by 1e-2 and moved 1000 away.
std::vector<Vertex> extremeVertices(float phase) {
    const float nan = std::numeric_limits<float>::quiet_NaN();
    return {{-1e4f, -20.0f, -1e4f, 0},
            {1e4f, -20.0f, -1e4f, 0},
            {0, -20.0f, 1e4f, 0},
            {0, 0.5f + 1e-4f * phase, 0, 0},
            {1e-3f, 0.5f, 0, 0},
            {0, 0.5f, 1e-3f, 0},
            {1, 1, 1, 0},
            {1, 1, 1, 0},
            {2, 2 + phase, 2, 0},
            {nan, 0, 0, 0},
            {1, 0, 0, 0},
            {0, 0, 1, 0},
            {-2, 0.2f + 0.1f * phase, -2, 0},
            {-1, 0.2f, -2, 0},
            {-1, 0.2f, -1, 0},
            {-2, 0.2f, -1, 0}};
}
std::vector<uint32_t> extremeIndices() {
    return {0, 1, 2, 3, 5, 4, 6, 7, 8, 9, 10, 11, 12, 14, 13, 12, 15, 14};
}
std::vector<Box> extremeBoxes(float lift) {
    const float nan = std::numeric_limits<float>::quiet_NaN();
    return {{{-3, 0, -3}, {-2, 1 + lift, -2}, {0, 0}},
            {{-1, 0.5f, -3}, {0, 0.5f, -2}, {0, 0}},
            {{nan, 0, 0}, {1, 1, 1}, {0, 0}},
            {{1, 0, 1}, {1.001f, 0.001f, 1.001f}, {0, 0}},
            {{2, 0, 2}, {3, 1 + lift, 3}, {0, 0}},
            {{2, 0, 2}, {3, 1 + lift, 3}, {0, 0}},
            {{-1000, -5, -1000}, {1000, -4, 1000}, {0, 0}},
            {{0, 0, 0}, {0.5f, 0.5f + lift, 0.5f}, {0, 0}}};
}

void setTransform(VkAccelerationStructureInstanceNV& inst, float yaw, float scale, float tx,
                  float ty, float tz) {
    const float c = std::cos(yaw) * scale, s = std::sin(yaw) * scale;
    const float m[12] = {c, 0, s, tx, 0, scale, 0, ty, -s, 0, c, tz};
    std::memcpy(inst.transform.matrix, m, sizeof m);
}

struct NvObject {
    VkAccelerationStructureNV handle = VK_NULL_HANDLE;
    VkDeviceMemory memory = VK_NULL_HANDLE;
    uint64_t deviceHandle = 0;
    VkDeviceSize buildScratch = 0, updateScratch = 0;
};

NvObject createNv(Vulkan& v, const VkAccelerationStructureInfoNV& info) {
    auto create = v.proc<PFN_vkCreateAccelerationStructureNV>("vkCreateAccelerationStructureNV");
    auto requirements = v.proc<PFN_vkGetAccelerationStructureMemoryRequirementsNV>(
        "vkGetAccelerationStructureMemoryRequirementsNV");
    auto bind =
        v.proc<PFN_vkBindAccelerationStructureMemoryNV>("vkBindAccelerationStructureMemoryNV");
    auto handle =
        v.proc<PFN_vkGetAccelerationStructureHandleNV>("vkGetAccelerationStructureHandleNV");
    NvObject o;
    VkAccelerationStructureCreateInfoNV ci{VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_CREATE_INFO_NV};
    ci.info = info;
    CHECK(create(v.device, &ci, nullptr, &o.handle));
    VkAccelerationStructureMemoryRequirementsInfoNV ri{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_INFO_NV};
    ri.accelerationStructure = o.handle;
    VkMemoryRequirements2 r{VK_STRUCTURE_TYPE_MEMORY_REQUIREMENTS_2};
    ri.type = VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_BUILD_SCRATCH_NV;
    requirements(v.device, &ri, &r);
    o.buildScratch = r.memoryRequirements.size;
    ri.type = VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_UPDATE_SCRATCH_NV;
    requirements(v.device, &ri, &r);
    o.updateScratch = r.memoryRequirements.size;
    ri.type = VK_ACCELERATION_STRUCTURE_MEMORY_REQUIREMENTS_TYPE_OBJECT_NV;
    requirements(v.device, &ri, &r);
    o.memory = v.allocate(r.memoryRequirements, VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT, false);
    VkBindAccelerationStructureMemoryInfoNV bi{
        VK_STRUCTURE_TYPE_BIND_ACCELERATION_STRUCTURE_MEMORY_INFO_NV};
    bi.accelerationStructure = o.handle;
    bi.memory = o.memory;
    CHECK(bind(v.device, 1, &bi));
    CHECK(handle(v.device, o.handle, sizeof o.deviceHandle, &o.deviceHandle));
    return o;
}

// ---- Rays ----------------------------------------------------------------------------------

// Half a 64x32 grid looking down at the scene at a slant, half seeded random rays through it.
std::vector<NvTracedRay> sceneRays(uint32_t count) {
    std::vector<NvTracedRay> rays;
    Random random{0xC1A57ACEull};
    const uint32_t grid = count / 2;
    for (uint32_t i = 0; i < count; ++i) {
        NvTracedRay r{};
        float o[3], target[3];
        if (i < grid) {
            const float u = (float(i % 64) + 0.5f) / 64.0f, w = (float(i / 64 % 32) + 0.5f) / 32.0f;
            o[0] = -1.0f + 2.0f * u;
            o[1] = 12.0f;
            o[2] = 14.0f - 4.0f * w;
            target[0] = -9.0f + 18.0f * u;
            target[1] = 0.0f;
            target[2] = -9.0f + 18.0f * w;
        } else {
            for (int k = 0; k < 3; ++k) {
                o[k] = -14.0f + 28.0f * random.uniform();
                target[k] = (k == 1 ? -1.0f : -8.0f) + (k == 1 ? 4.0f : 16.0f) * random.uniform();
            }
        }
        float d[3] = {target[0] - o[0], target[1] - o[1], target[2] - o[2]};
        const float len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        for (int k = 0; k < 3; ++k) {
            r.origin[k] = o[k];
            r.direction[k] = d[k] / len;
            if (r.direction[k] == 0.0f)
                r.direction[k] = 1e-6f;  // no exact zero: 1/0 in the slab test
        }
        r.t_min = (i % 7 == 3) ? 0.5f : 0.0f;
        r.t_max = (i % 11 == 5) ? 14.0f : 1000.0f;
        r.ray_flags = (i % 13 == 4) ? 0x10u : 0u;  // gl_RayFlagsCullBackFacingTrianglesNV
        r.cull_mask = (i % 5 == 2) ? 0x02u : 0xFFu;
        rays.push_back(r);
    }
    return rays;
}

// ---- Start-up ------------------------------------------------------------------------------

struct AppOptions {
    bool probe = false, require = false, skipKhr = false, extremes = false;
    uint32_t rayCount = 4096;
};

bool parseArgs(int argc, char** argv, AppOptions& o) {
    for (int i = 1; i < argc; ++i) {
        const std::string a = argv[i];
        if (a == "--probe")
            o.probe = true;
        else if (a == "--require")
            o.require = true;
        else if (a == "--no-khr")
            o.skipKhr = true;
        else if (a == "--extremes")
            o.extremes = true;
        else if (a == "--rays" && i + 1 < argc)
            o.rayCount = uint32_t(std::strtoul(argv[++i], nullptr, 10));
        else {
            std::fprintf(stderr,
                         "usage: nv_ray_tracing_app [--probe] [--require] [--no-khr] [--extremes] "
                         "[--rays N]\n");
            return false;
        }
    }
    return true;
}

void createInstance(Vulkan& v) {
    VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
    app.pApplicationName = "nv_ray_tracing_app";
    app.pEngineName = "clastrace tests";
    app.apiVersion = VK_API_VERSION_1_2;
    VkInstanceCreateInfo ici{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
    ici.pApplicationInfo = &app;
    CHECK(vkCreateInstance(&ici, nullptr, &v.instance));
}

// The first device with VK_NV_ray_tracing (else the first device); returns its extensions.
std::vector<VkExtensionProperties> pickPhysicalDevice(Vulkan& v) {
    uint32_t count = 0;
    CHECK(vkEnumeratePhysicalDevices(v.instance, &count, nullptr));
    std::vector<VkPhysicalDevice> physicals(count);
    CHECK(vkEnumeratePhysicalDevices(v.instance, &count, physicals.data()));
    std::vector<VkExtensionProperties> extensions;
    for (VkPhysicalDevice p : physicals) {
        uint32_t n = 0;
        vkEnumerateDeviceExtensionProperties(p, nullptr, &n, nullptr);
        std::vector<VkExtensionProperties> list(n);
        vkEnumerateDeviceExtensionProperties(p, nullptr, &n, list.data());
        if (!v.physical || hasExtension(list, VK_NV_RAY_TRACING_EXTENSION_NAME)) {
            const bool better =
                !v.physical || !hasExtension(extensions, VK_NV_RAY_TRACING_EXTENSION_NAME);
            if (better) {
                v.physical = p;
                extensions = list;
            }
        }
    }
    if (!v.physical) die("no Vulkan device");
    return extensions;
}

uint32_t computeFamily(VkPhysicalDevice physical) {
    uint32_t familyCount = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(physical, &familyCount, nullptr);
    std::vector<VkQueueFamilyProperties> families(familyCount);
    vkGetPhysicalDeviceQueueFamilyProperties(physical, &familyCount, families.data());
    for (uint32_t i = 0; i < familyCount; ++i)
        if (families[i].queueFlags & VK_QUEUE_COMPUTE_BIT) return i;
    die("no compute queue");
}

// The device with VK_NV_ray_tracing (and the KHR acceleration structures when v.khr), its
// queue, properties and command pool.
void createDevice(Vulkan& v) {
    v.family = computeFamily(v.physical);
    std::vector<const char*> enabled = {VK_NV_RAY_TRACING_EXTENSION_NAME};
    VkPhysicalDeviceVulkan12Features features12{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES};
    features12.bufferDeviceAddress = VK_TRUE;
    VkPhysicalDeviceAccelerationStructureFeaturesKHR asFeatures{
        VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_ACCELERATION_STRUCTURE_FEATURES_KHR};
    asFeatures.accelerationStructure = VK_TRUE;
    if (v.khr) {
        enabled.push_back(VK_KHR_ACCELERATION_STRUCTURE_EXTENSION_NAME);
        enabled.push_back(VK_KHR_DEFERRED_HOST_OPERATIONS_EXTENSION_NAME);
        features12.pNext = &asFeatures;
    }
    const float priority = 1.0f;
    VkDeviceQueueCreateInfo qci{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
    qci.queueFamilyIndex = v.family;
    qci.queueCount = 1;
    qci.pQueuePriorities = &priority;
    VkDeviceCreateInfo dci{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO};
    dci.pNext = &features12;
    dci.queueCreateInfoCount = 1;
    dci.pQueueCreateInfos = &qci;
    dci.enabledExtensionCount = uint32_t(enabled.size());
    dci.ppEnabledExtensionNames = enabled.data();
    CHECK(vkCreateDevice(v.physical, &dci, nullptr, &v.device));
    vkGetDeviceQueue(v.device, v.family, 0, &v.queue);
    vkGetPhysicalDeviceMemoryProperties(v.physical, &v.memory);
    v.rt.pNext = v.khr ? &v.asProperties : nullptr;
    VkPhysicalDeviceProperties2 p2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &v.rt};
    vkGetPhysicalDeviceProperties2(v.physical, &p2);
    v.rt.pNext = nullptr;
    VkCommandPoolCreateInfo pci{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
    pci.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
    pci.queueFamilyIndex = v.family;
    CHECK(vkCreateCommandPool(v.device, &pci, nullptr, &v.pool));
}

// ---- NV bottom levels and top level -----------------------------------------------------------

// The NV scene's buffers, geometries and structures. The build infos point into it: it is
// filled in place and never moved.
struct NvStructures {
    bool extremes = false;
    Vulkan::Buffer vertices, indices, transforms, tetraVertices, tetraIndices, boxBuffer,
        instanceBuffer, scratch;
    uint32_t vertexCount = 0, indexCount = 0;
    VkGeometryNV triangleGeometries[2] = {};
    VkGeometryNV aabbGeometry{VK_STRUCTURE_TYPE_GEOMETRY_NV};
    VkAccelerationStructureInfoNV triangleInfo{VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_INFO_NV};
    VkAccelerationStructureInfoNV aabbInfo{VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_INFO_NV};
    VkAccelerationStructureInfoNV topInfo{VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_INFO_NV};
    NvObject triangleBlas, aabbBlas, tlas;
    // Instances: (custom index, mask, SBT offset, flags) each different; instance 4 has mask 0.
    static constexpr uint32_t kInstances = 5;
    std::vector<VkAccelerationStructureInstanceNV> instances =
        std::vector<VkAccelerationStructureInstanceNV>(kInstances);
    std::vector<Box> boxValues;  // the boxes as last written

    std::vector<Vertex> sceneVertices(float phase) const {
        return extremes ? extremeVertices(phase) : heightField(phase);
    }
    std::vector<Box> sceneBoxes(float lift) const {
        return extremes ? extremeBoxes(lift) : boxes(lift);
    }
};

void uploadInputs(Vulkan& v, NvStructures& s) {
    const VkBufferUsageFlags input = VK_BUFFER_USAGE_RAY_TRACING_BIT_NV;
    const auto firstVertices = s.sceneVertices(0.0f);
    const auto gridIndices = s.extremes ? extremeIndices() : heightFieldIndices();
    s.vertexCount = uint32_t(firstVertices.size());
    s.indexCount = uint32_t(gridIndices.size());
    s.vertices = v.upload(firstVertices, input);
    s.indices = v.upload(gridIndices, input);
    // Two 3x4 transforms at offsets 0 and 48; geometry 0 uses the second (offset 48).
    std::vector<float> transforms = {1,    0, 0, 0,    0, 1, 0, 0,     0, 0, 1,    0,
                                     1.2f, 0, 0, 0.5f, 0, 1, 0, 0.25f, 0, 0, 1.2f, -0.5f};
    s.transforms = v.upload(transforms, input);
    const std::vector<float> tetraVertices = {0,    1.5f, 0,     -0.6f, 0.6f, -0.6f,
                                              0.6f, 0.6f, -0.6f, 0,     0.6f, 0.7f};
    const std::vector<uint16_t> tetraIndices = {0, 1, 2, 0, 2, 3, 0, 3, 1, 1, 3, 2};
    s.tetraVertices = v.upload(tetraVertices, input);
    s.tetraIndices = v.upload(tetraIndices, input);
    s.boxValues = s.sceneBoxes(0.0f);
    s.boxBuffer = v.upload(s.boxValues, input);
}

void describeTriangles(NvStructures& s) {
    for (auto& g : s.triangleGeometries) {
        g.sType = VK_STRUCTURE_TYPE_GEOMETRY_NV;
        g.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_NV;
        g.geometry.triangles.sType = VK_STRUCTURE_TYPE_GEOMETRY_TRIANGLES_NV;
        g.geometry.aabbs.sType = VK_STRUCTURE_TYPE_GEOMETRY_AABB_NV;
        g.flags = VK_GEOMETRY_OPAQUE_BIT_NV;
    }
    auto& grid = s.triangleGeometries[0].geometry.triangles;
    grid.vertexData = s.vertices.buffer;
    grid.vertexCount = s.vertexCount;
    grid.vertexStride = sizeof(Vertex);
    grid.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    grid.indexData = s.indices.buffer;
    grid.indexCount = s.indexCount;
    grid.indexType = VK_INDEX_TYPE_UINT32;
    grid.transformData = s.transforms.buffer;
    grid.transformOffset = 48;
    auto& tetra = s.triangleGeometries[1].geometry.triangles;
    tetra.vertexData = s.tetraVertices.buffer;
    tetra.vertexCount = 4;
    tetra.vertexStride = 12;
    tetra.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    tetra.indexData = s.tetraIndices.buffer;
    tetra.indexCount = 12;
    tetra.indexType = VK_INDEX_TYPE_UINT16;
    s.triangleGeometries[1].flags = 0;  // not opaque: exercises the no-any-hit path
    s.triangleInfo.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
    s.triangleInfo.flags = VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_NV |
                           VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_TRACE_BIT_NV;
    s.triangleInfo.geometryCount = 2;
    s.triangleInfo.pGeometries = s.triangleGeometries;
}

void describeBoxes(NvStructures& s) {
    s.aabbGeometry.geometryType = VK_GEOMETRY_TYPE_AABBS_NV;
    s.aabbGeometry.geometry.triangles.sType = VK_STRUCTURE_TYPE_GEOMETRY_TRIANGLES_NV;
    s.aabbGeometry.geometry.aabbs.sType = VK_STRUCTURE_TYPE_GEOMETRY_AABB_NV;
    s.aabbGeometry.geometry.aabbs.aabbData = s.boxBuffer.buffer;
    s.aabbGeometry.geometry.aabbs.numAABBs = 8;
    s.aabbGeometry.geometry.aabbs.stride = sizeof(Box);
    s.aabbGeometry.flags = VK_GEOMETRY_OPAQUE_BIT_NV;
    s.aabbInfo.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
    s.aabbInfo.flags = VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_NV;
    s.aabbInfo.geometryCount = 1;
    s.aabbInfo.pGeometries = &s.aabbGeometry;
}

void fillInstances(NvStructures& s, float t) {
    auto& instances = s.instances;
    setTransform(instances[0], 0.0f, 1.0f, -4.0f, 0.0f, -3.0f);
    setTransform(instances[1], 0.6f + t, 0.8f, 4.0f, 0.5f, -2.0f);
    setTransform(instances[2], 0.0f, 1.0f, -3.0f, 0.2f + t, 4.0f);
    setTransform(instances[3], -0.4f, 1.5f, 4.5f, 0.0f, 4.5f);
    setTransform(instances[4], 0.0f, 1.0f, 0.0f, -2.0f, 0.0f);
    if (s.extremes) {
        // Mirrored (x negated: front faces turn back), a hundredth the size, 1000 away.
        const float mirrored[12] = {-0.8f, 0, 0, 4.0f, 0, 0.8f, 0, 0.5f + t, 0, 0, 0.8f, -2.0f};
        std::memcpy(instances[1].transform.matrix, mirrored, sizeof mirrored);
        setTransform(instances[2], 0.0f, 0.01f, -3.0f, 0.2f + t, 4.0f);
        setTransform(instances[3], -0.4f, 1.5f, 1000.0f, 0.0f, 1000.0f);
    }
    constexpr uint32_t n = NvStructures::kInstances;
    const uint32_t custom[n] = {10, 11, 12, 0xABCDE, 14};
    const uint32_t masks[n] = {0xFF, 0x01, 0xFF, 0x02, 0x00};
    const uint32_t offsets[n] = {0, 0, 2, 2, 0};
    const uint32_t flags[n] = {0, VK_GEOMETRY_INSTANCE_TRIANGLE_CULL_DISABLE_BIT_NV,
                               VK_GEOMETRY_INSTANCE_FORCE_OPAQUE_BIT_NV,
                               VK_GEOMETRY_INSTANCE_TRIANGLE_FRONT_COUNTERCLOCKWISE_BIT_NV, 0};
    for (uint32_t i = 0; i < n; ++i) {
        instances[i].instanceCustomIndex = custom[i];
        instances[i].mask = masks[i];
        instances[i].instanceShaderBindingTableRecordOffset = offsets[i];
        instances[i].flags = flags[i];
        instances[i].accelerationStructureReference =
            (i == 2 || i == 3) ? s.aabbBlas.deviceHandle : s.triangleBlas.deviceHandle;
    }
}

void createStructures(Vulkan& v, NvStructures& s) {
    uploadInputs(v, s);
    describeTriangles(s);
    describeBoxes(s);
    s.triangleBlas = createNv(v, s.triangleInfo);
    s.aabbBlas = createNv(v, s.aabbInfo);
    fillInstances(s, 0.0f);
    s.instanceBuffer = v.upload(s.instances, VK_BUFFER_USAGE_RAY_TRACING_BIT_NV);
    s.topInfo.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
    s.topInfo.flags = VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_UPDATE_BIT_NV;
    s.topInfo.instanceCount = NvStructures::kInstances;
    s.tlas = createNv(v, s.topInfo);
    VkDeviceSize scratchSize = 0;
    for (const NvObject* o : {&s.triangleBlas, &s.aabbBlas, &s.tlas})
        scratchSize = std::max({scratchSize, o->buildScratch, o->updateScratch});
    s.scratch = v.buffer(scratchSize, VK_BUFFER_USAGE_RAY_TRACING_BIT_NV, false);
}

void buildAll(Vulkan& v, NvStructures& s, bool update) {
    auto build = v.proc<PFN_vkCmdBuildAccelerationStructureNV>("vkCmdBuildAccelerationStructureNV");
    v.submit([&](VkCommandBuffer cb) {
        // One scratch buffer for all three: each build waits for the one before.
        build(cb, &s.triangleInfo, VK_NULL_HANDLE, 0, update, s.triangleBlas.handle,
              update ? s.triangleBlas.handle : VK_NULL_HANDLE, s.scratch.buffer, 0);
        asBarrier(cb);
        build(cb, &s.aabbInfo, VK_NULL_HANDLE, 0, update, s.aabbBlas.handle,
              update ? s.aabbBlas.handle : VK_NULL_HANDLE, s.scratch.buffer, 0);
        asBarrier(cb);
        build(cb, &s.topInfo, s.instanceBuffer.buffer, 0, update, s.tlas.handle,
              update ? s.tlas.handle : VK_NULL_HANDLE, s.scratch.buffer, 0);
        asBarrier(cb);
    });
}

// Refit: same topology, moved vertices, boxes and instances.
void refit(Vulkan& v, NvStructures& s) {
    const auto moved = s.sceneVertices(0.8f);
    std::memcpy(s.vertices.mapped, moved.data(), moved.size() * sizeof(Vertex));
    s.boxValues = s.sceneBoxes(0.25f);
    std::memcpy(s.boxBuffer.mapped, s.boxValues.data(), s.boxValues.size() * sizeof(Box));
    fillInstances(s, 0.3f);
    std::memcpy(s.instanceBuffer.mapped, s.instances.data(),
                s.instances.size() * sizeof(s.instances[0]));
    buildAll(v, s, true);
}

// ---- The application's own rays ---------------------------------------------------------------

NvTraceScene traceScene(const NvStructures& s) {
    NvTraceScene scene;
    // Slots: 0-1 triangle bottom level's geometries, 2 the AABB geometry.
    scene.geometry_is_aabb = {0, 0, 1};
    scene.geometry_first_box = {0, 0, 0};
    for (const Box& b : s.boxValues)
        scene.boxes.insert(scene.boxes.end(),
                           {b.lo[0], b.lo[1], b.lo[2], b.hi[0], b.hi[1], b.hi[2]});
    for (uint32_t i = 0; i < NvStructures::kInstances; ++i)
        scene.instances.push_back(
            {s.instances[i].instanceShaderBindingTableRecordOffset, (i == 2 || i == 3) ? 2u : 0u});
    scene.record_is_procedural = {0, 0, 1};
    return scene;
}

void printHits(const std::vector<NvRayHit>& hits, size_t rayCount) {
    constexpr uint32_t n = NvStructures::kInstances;
    uint32_t hitCount = 0, perInstance[n] = {}, procedural = 0;
    uint64_t digest = 1469598103934665603ull;
    for (const NvRayHit& h : hits) {
        if (h.hit) {
            ++hitCount;
            if (h.instance_id < n) ++perInstance[h.instance_id];
            procedural += h.hit_kind == 0;
        }
        // Fields only: the shaders leave the padding words undefined.
        for (size_t k = 0; k < offsetof(NvRayHit, pad); ++k)
            digest = (digest ^ reinterpret_cast<const uint8_t*>(&h)[k]) * 1099511628211ull;
    }
    std::printf(
        "nv_ray_tracing_app: traced %zu rays: %u hits (instances %u %u %u %u %u; %u on boxes), "
        "digest %016" PRIx64 "\n",
        rayCount, hitCount, perInstance[0], perInstance[1], perInstance[2], perInstance[3],
        perInstance[4], procedural, digest);
    for (size_t i = 0; i < 3 && i < hits.size(); ++i)
        std::printf(
            "nv_ray_tracing_app: ray %zu: hit %u t %.6f custom %u instance %u primitive %u "
            "geometry %u kind 0x%x "
            "uv (%.4f %.4f)\n",
            i, hits[i].hit, hits[i].t, hits[i].instance_custom_index, hits[i].instance_id,
            hits[i].primitive_id, hits[i].geometry_index, hits[i].hit_kind, hits[i].u, hits[i].v);
}

void traceAppRays(Vulkan& v, const NvStructures& s, uint32_t rayCount) {
    const NvTraceScene scene = traceScene(s);
    clastrace::capture::NvRayTracerContext context;
    context.device = v.device;
    context.queue = v.queue;
    context.queue_family_index = v.family;
    context.get_device_proc_addr = vkGetDeviceProcAddr;
    context.memory_properties = v.memory;
    context.ray_tracing_properties = v.rt;
    const auto rays = sceneRays(rayCount);
    std::vector<NvRayHit> hits;
    std::string error;
    if (!clastrace::capture::trace_rays_nv(context, s.tlas.handle, scene, rays, hits, error))
        die("tracing rays: " + error);
    printHits(hits, rays.size());
}

// ---- KHR: build, serialize, deserialize -------------------------------------------------------

VkAccelerationStructureKHR makeKhr(Vulkan& v, VkDeviceSize size, Vulkan::Buffer& backing) {
    auto createKhr =
        v.proc<PFN_vkCreateAccelerationStructureKHR>("vkCreateAccelerationStructureKHR");
    auto addressOf = v.proc<PFN_vkGetAccelerationStructureDeviceAddressKHR>(
        "vkGetAccelerationStructureDeviceAddressKHR");
    backing = v.buffer(size, VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR, false, true);
    VkAccelerationStructureCreateInfoKHR ci{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_CREATE_INFO_KHR};
    ci.buffer = backing.buffer;
    ci.size = size;
    ci.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    VkAccelerationStructureKHR as;
    CHECK(createKhr(v.device, &ci, nullptr, &as));
    VkAccelerationStructureDeviceAddressInfoKHR ai{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_DEVICE_ADDRESS_INFO_KHR};
    ai.accelerationStructure = as;
    const VkDeviceAddress address = addressOf(v.device, &ai);
    std::printf("nv_ray_tracing_app: KHR structure of %" PRIu64 " bytes at 0x%016" PRIx64 "\n",
                uint64_t(size), uint64_t(address));
    return as;
}

// A KHR bottom level: its inputs, its structure and the build's scratch, kept alive together.
struct KhrQuad {
    Vulkan::Buffer vertices, indices, backing, scratch;
    VkAccelerationStructureKHR structure = VK_NULL_HANDLE;
    VkDeviceSize size = 0;
};

// Builds a two-triangle quad and returns its serialized size (a query after the build).
uint64_t buildKhrQuad(Vulkan& v, KhrQuad& q) {
    auto sizes = v.proc<PFN_vkGetAccelerationStructureBuildSizesKHR>(
        "vkGetAccelerationStructureBuildSizesKHR");
    auto buildKhr =
        v.proc<PFN_vkCmdBuildAccelerationStructuresKHR>("vkCmdBuildAccelerationStructuresKHR");
    auto writeProperties = v.proc<PFN_vkCmdWriteAccelerationStructuresPropertiesKHR>(
        "vkCmdWriteAccelerationStructuresPropertiesKHR");
    const std::vector<float> quad = {-1, 0, -1, 1, 0, -1, 1, 0, 1, -1, 0, 1};
    const std::vector<uint32_t> quadIndices = {0, 1, 2, 0, 2, 3};
    const VkBufferUsageFlags buildInput =
        VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
    q.vertices = v.upload(quad, buildInput, true);
    q.indices = v.upload(quadIndices, buildInput, true);
    VkAccelerationStructureGeometryKHR geometry{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR};
    geometry.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    geometry.flags = VK_GEOMETRY_OPAQUE_BIT_KHR;
    auto& t = geometry.geometry.triangles;
    t.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_TRIANGLES_DATA_KHR;
    t.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    t.vertexData.deviceAddress = q.vertices.address;
    t.vertexStride = 12;
    t.maxVertex = 3;
    t.indexType = VK_INDEX_TYPE_UINT32;
    t.indexData.deviceAddress = q.indices.address;
    VkAccelerationStructureBuildGeometryInfoKHR buildInfo{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR};
    buildInfo.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    buildInfo.flags = VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_TRACE_BIT_KHR;
    buildInfo.mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_BUILD_KHR;
    buildInfo.geometryCount = 1;
    buildInfo.pGeometries = &geometry;
    const uint32_t primitives = 2;
    VkAccelerationStructureBuildSizesInfoKHR sizeInfo{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_SIZES_INFO_KHR};
    sizes(v.device, VK_ACCELERATION_STRUCTURE_BUILD_TYPE_DEVICE_KHR, &buildInfo, &primitives,
          &sizeInfo);
    q.size = sizeInfo.accelerationStructureSize;
    q.structure = makeKhr(v, q.size, q.backing);
    const VkDeviceSize scratchAlign =
        std::max<VkDeviceSize>(v.asProperties.minAccelerationStructureScratchOffsetAlignment, 1);
    q.scratch = v.buffer(sizeInfo.buildScratchSize + scratchAlign,
                         VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, false, true);
    buildInfo.dstAccelerationStructure = q.structure;
    buildInfo.scratchData.deviceAddress =
        (q.scratch.address + scratchAlign - 1) / scratchAlign * scratchAlign;
    VkAccelerationStructureBuildRangeInfoKHR range{primitives, 0, 0, 0};
    const VkAccelerationStructureBuildRangeInfoKHR* ranges = &range;

    VkQueryPoolCreateInfo qpi{VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO};
    qpi.queryType = VK_QUERY_TYPE_ACCELERATION_STRUCTURE_SERIALIZATION_SIZE_KHR;
    qpi.queryCount = 1;
    VkQueryPool queries;
    CHECK(vkCreateQueryPool(v.device, &qpi, nullptr, &queries));
    v.submit([&](VkCommandBuffer cb) {
        vkCmdResetQueryPool(cb, queries, 0, 1);
        buildKhr(cb, 1, &buildInfo, &ranges);
        VkMemoryBarrier b{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                          VK_ACCESS_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                          VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR};
        vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                             VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, 0, 1, &b, 0,
                             nullptr, 0, nullptr);
        writeProperties(cb, 1, &q.structure,
                        VK_QUERY_TYPE_ACCELERATION_STRUCTURE_SERIALIZATION_SIZE_KHR, queries, 0);
    });
    uint64_t serializedSize = 0;
    CHECK(vkGetQueryPoolResults(v.device, queries, 0, 1, sizeof serializedSize, &serializedSize,
                                sizeof serializedSize,
                                VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT));
    vkDestroyQueryPool(v.device, queries, nullptr);
    return serializedSize;
}

void khrRoundTrip(Vulkan& v) {
    auto toMemory = v.proc<PFN_vkCmdCopyAccelerationStructureToMemoryKHR>(
        "vkCmdCopyAccelerationStructureToMemoryKHR");
    auto fromMemory = v.proc<PFN_vkCmdCopyMemoryToAccelerationStructureKHR>(
        "vkCmdCopyMemoryToAccelerationStructureKHR");
    KhrQuad source;
    const uint64_t serializedSize = buildKhrQuad(v, source);
    // The blob's address must be 256-byte aligned: over-allocate and align inside the buffer.
    auto blob = v.buffer(serializedSize + 256,
                         VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR |
                             VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                         true, true);
    const VkDeviceAddress blobAddress = (blob.address + 255) / 256 * 256;
    v.submit([&](VkCommandBuffer cb) {
        VkCopyAccelerationStructureToMemoryInfoKHR ci{
            VK_STRUCTURE_TYPE_COPY_ACCELERATION_STRUCTURE_TO_MEMORY_INFO_KHR};
        ci.src = source.structure;
        ci.dst.deviceAddress = blobAddress;
        ci.mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_SERIALIZE_KHR;
        toMemory(cb, &ci);
    });
    const uint8_t* header = static_cast<const uint8_t*>(blob.mapped) + (blobAddress - blob.address);
    uint64_t headerSizes[3];
    std::memcpy(headerSizes, header + 32, sizeof headerSizes);
    std::printf("nv_ray_tracing_app: serialized KHR structure: %" PRIu64 " bytes (query %" PRIu64
                "), deserialized size %" PRIu64 ", %" PRIu64 " handles, driver UUID %s\n",
                headerSizes[0], serializedSize, headerSizes[1], headerSizes[2],
                hex(header, 16).c_str());
    Vulkan::Buffer copyBacking;
    VkAccelerationStructureKHR copy =
        makeKhr(v, std::max<VkDeviceSize>(headerSizes[1], source.size), copyBacking);
    v.submit([&](VkCommandBuffer cb) {
        VkCopyMemoryToAccelerationStructureInfoKHR ci{
            VK_STRUCTURE_TYPE_COPY_MEMORY_TO_ACCELERATION_STRUCTURE_INFO_KHR};
        ci.src.deviceAddress = blobAddress;
        ci.dst = copy;
        ci.mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_DESERIALIZE_KHR;
        fromMemory(cb, &ci);
    });
    std::printf("nv_ray_tracing_app: deserialized into a new KHR structure\n");
}

}  // namespace

int main(int argc, char** argv) {
    AppOptions options;
    if (!parseArgs(argc, argv, options)) return 2;
    Vulkan v;
    createInstance(v);
    const std::vector<VkExtensionProperties> extensions = pickPhysicalDevice(v);
    if (options.probe) printProbe(v, extensions);
    VkPhysicalDeviceProperties properties;
    vkGetPhysicalDeviceProperties(v.physical, &properties);
    if (!hasExtension(extensions, VK_NV_RAY_TRACING_EXTENSION_NAME)) {
        std::printf(
            "nv_ray_tracing_app: VK_NV_ray_tracing not available on '%s': skipping the NV "
            "ray-tracing scene\n",
            properties.deviceName);
        vkDestroyInstance(v.instance, nullptr);
        return options.require ? 77 : 0;
    }
    if (options.probe) {
        vkDestroyInstance(v.instance, nullptr);
        return 0;
    }
    v.khr = !options.skipKhr &&
            hasExtension(extensions, VK_KHR_ACCELERATION_STRUCTURE_EXTENSION_NAME) &&
            hasExtension(extensions, VK_KHR_DEFERRED_HOST_OPERATIONS_EXTENSION_NAME);
    createDevice(v);
    std::printf(
        "nv_ray_tracing_app: device '%s', driverVersion 0x%08x, KHR acceleration structures %s\n",
        properties.deviceName, properties.driverVersion, v.khr ? "on" : "off");

    NvStructures s;
    s.extremes = options.extremes;
    createStructures(v, s);
    buildAll(v, s, false);
    std::printf("nv_ray_tracing_app: built NV bottom levels 0x%016" PRIx64 " 0x%016" PRIx64
                " and top level 0x%016" PRIx64 "\n",
                s.triangleBlas.deviceHandle, s.aabbBlas.deviceHandle, s.tlas.deviceHandle);
    refit(v, s);
    std::printf("nv_ray_tracing_app: updated (refit) the three NV structures\n");
    traceAppRays(v, s, options.rayCount);
    if (v.khr) khrRoundTrip(v);

    vkDeviceWaitIdle(v.device);
    // The layer finishes its trace at exit; objects die with the device.
    vkDestroyDevice(v.device, nullptr);
    vkDestroyInstance(v.instance, nullptr);
    std::printf("nv_ray_tracing_app: done\n");
    return 0;
}
