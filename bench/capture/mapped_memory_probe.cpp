// SPDX-License-Identifier: Apache-2.0
// What a driver's mapped memory costs the layer's host-write watch, per host-visible memory
// type: memcpy read and write speed against malloc'd memory (is the mapping really uncached?),
// and whether mprotect(PROT_READ) is accepted on it, with the cost of a write fault whose
// handler makes the page writable again (what the page guard pays). docs/benchmarks.md
// "Device run, session 11" has the NVIDIA numbers.
//   mapped_memory_probe [megabytes=8]
#include <vulkan/vulkan.h>

#include <sys/mman.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

namespace {

std::atomic<int> g_faults{0};  // lock-free: safe in the handler
long g_page = 4096;

void make_page_writable(int, siginfo_t* info, void*) {
    ++g_faults;
    void* page = reinterpret_cast<void*>(reinterpret_cast<uintptr_t>(info->si_addr) &
                                         ~uintptr_t(g_page - 1));
    if (mprotect(page, size_t(g_page), PROT_READ | PROT_WRITE) != 0) _exit(3);
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// GB/s of `reps` memcpy calls of `size` bytes from `src` to `dst`.
double copy_rate(void* dst, const void* src, size_t size, int reps) {
    const auto t0 = std::chrono::steady_clock::now();
    for (int r = 0; r < reps; ++r) {
        std::memcpy(dst, src, size);
        asm volatile("" ::: "memory");  // every copy happens
    }
    return double(size) * reps / seconds_since(t0) / 1e9;
}

void probe_guard(uint8_t* mapped, size_t size) {
    auto t0 = std::chrono::steady_clock::now();
    const int rc = mprotect(mapped, size, PROT_READ);
    const double protect_us = seconds_since(t0) * 1e6;
    std::printf("  mprotect(PROT_READ): %s, %.1f us\n", rc == 0 ? "accepted" : std::strerror(errno),
                protect_us);
    if (rc != 0) return;
    g_faults = 0;
    const size_t pages = size / size_t(g_page), step = 16;
    t0 = std::chrono::steady_clock::now();
    for (size_t p = 0; p < pages; p += step) mapped[p * size_t(g_page) + 5] = 7;
    const double fault_us = seconds_since(t0) * 1e6 / double((pages + step - 1) / step);
    std::printf("  writes to %zu protected pages: %d faults, %.2f us a fault\n",
                (pages + step - 1) / step, g_faults.load(), fault_us);
    mprotect(mapped, size, PROT_READ | PROT_WRITE);
}

}  // namespace

int main(int argc, char** argv) {
    const size_t size = size_t(argc > 1 ? std::max(1, std::atoi(argv[1])) : 8) << 20;
    g_page = sysconf(_SC_PAGESIZE);
    struct sigaction action = {};
    action.sa_sigaction = make_page_writable;
    action.sa_flags = SA_SIGINFO;
    sigaction(SIGSEGV, &action, nullptr);

    VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
    app.apiVersion = VK_API_VERSION_1_2;
    VkInstanceCreateInfo instance_info{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
    instance_info.pApplicationInfo = &app;
    VkInstance instance;
    if (vkCreateInstance(&instance_info, nullptr, &instance) != VK_SUCCESS) {
        std::fprintf(stderr, "mapped_memory_probe: no Vulkan instance\n");
        return 1;
    }
    uint32_t count = 1;
    VkPhysicalDevice gpu;
    if (vkEnumeratePhysicalDevices(instance, &count, &gpu) < 0 || count == 0) {
        std::fprintf(stderr, "mapped_memory_probe: no physical device\n");
        return 1;
    }
    VkPhysicalDeviceProperties props;
    vkGetPhysicalDeviceProperties(gpu, &props);
    const float priority = 1;
    VkDeviceQueueCreateInfo queue{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
    queue.queueCount = 1;
    queue.pQueuePriorities = &priority;
    VkDeviceCreateInfo device_info{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO};
    device_info.queueCreateInfoCount = 1;
    device_info.pQueueCreateInfos = &queue;
    VkDevice device;
    if (vkCreateDevice(gpu, &device_info, nullptr, &device) != VK_SUCCESS) {
        std::fprintf(stderr, "mapped_memory_probe: no device\n");
        return 1;
    }
    std::printf("%s, %zu MB per memory type\n", props.deviceName, size >> 20);
    std::vector<uint8_t> host(size, 2), scratch(size, 3);
    VkPhysicalDeviceMemoryProperties memory;
    vkGetPhysicalDeviceMemoryProperties(gpu, &memory);
    for (uint32_t type = 0; type < memory.memoryTypeCount; ++type) {
        const VkMemoryPropertyFlags flags = memory.memoryTypes[type].propertyFlags;
        if (!(flags & VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT)) continue;
        VkMemoryAllocateInfo allocate{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
        allocate.allocationSize = size;
        allocate.memoryTypeIndex = type;
        VkDeviceMemory allocation;
        if (vkAllocateMemory(device, &allocate, nullptr, &allocation) != VK_SUCCESS) {
            std::printf("type %u (flags 0x%x): allocation refused\n", type, flags);
            continue;
        }
        void* mapped = nullptr;
        vkMapMemory(device, allocation, 0, VK_WHOLE_SIZE, 0, &mapped);
        auto* bytes = static_cast<uint8_t*>(mapped);
        std::memset(bytes, 1, size);
        // Uncached reads can run at tens of MB/s: one pass there.
        const int reps = (flags & VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT) ? 1 : 8;
        std::printf(
            "type %u (flags 0x%x, heap %u): memcpy read %.2f GB/s (malloc %.2f), write %.2f\n",
            type, flags, memory.memoryTypes[type].heapIndex,
            copy_rate(scratch.data(), bytes, size, reps),
            copy_rate(scratch.data(), host.data(), size, 8),
            copy_rate(bytes, host.data(), size, 8));
        probe_guard(bytes, size);
        vkUnmapMemory(device, allocation);
        vkFreeMemory(device, allocation, nullptr);
    }
    vkDestroyDevice(device, nullptr);
    vkDestroyInstance(instance, nullptr);
    return 0;
}
