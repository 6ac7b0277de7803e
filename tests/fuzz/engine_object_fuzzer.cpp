// SPDX-License-Identifier: Apache-2.0
// Fuzz target (docs/fuzzing.md): arbitrary bytes as an engine object at a device address,
// checked, traced, instantiated from and asked for its template indices. Nothing may
// crash, hang or read outside the bytes given.
#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/cluster_format.h"
#include "clastrace/engine/traversal.h"

#include <cstddef>
#include <cstdint>
#include <cstring>

using namespace clastrace::engine;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    const std::span<const std::byte> bytes(reinterpret_cast<const std::byte*>(data), size);
    if (const auto view = open_clas(bytes)) {
        const Ray rays[3] = {{{0.5f, 0.5f, 5}, 0, {0.01f, 0.02f, -1}, 100},
                             {{0, 0, 0}, 0, {1, 1, 1}, 1e30f},
                             {{-1e30f, 3, 2}, 0, {1, 0, 0}, 1e38f}};
        for (const Ray& r : rays) {
            (void)trace_closest(*view, r, 0);
            (void)trace_any(*view, r, kRayFlagCullBackFacingTriangles);
        }
    }
    if (size == 0) return 0;
    MemoryImage memory;
    const uint64_t base = 0x100000;
    memory.add_region(base, size, 0, "fuzz");
    std::memcpy(memory.write_bytes(base, size, {"fuzz", 0}).data(), data, size);
    VkClusterAccelerationStructureGetTemplateIndicesInfoNV gi{base};
    (void)get_cluster_template_indices(memory, gi, 0);
    VkClusterAccelerationStructureInstantiateClusterInfoNV ii{};
    ii.clusterTemplateAddress = base;
    VkClusterAccelerationStructureTriangleClusterInputNV input{};
    input.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    input.maxClusterTriangleCount = input.maxClusterVertexCount = 256;
    (void)instantiate_triangle_cluster(memory, ii, input, EngineProperties{}, 0);
    // The same bytes as a build info struct whose buffers point into the image.
    if (size >= sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV)) {
        VkClusterAccelerationStructureBuildTriangleClusterInfoNV info;
        std::memcpy(&info, data, sizeof info);
        info.indexBuffer = base + info.indexBuffer % size;
        info.vertexBuffer = base + info.vertexBuffer % size;
        (void)build_triangle_cluster(memory, info, input, EngineProperties{}, 0);
    }
    return 0;
}
