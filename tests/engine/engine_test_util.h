// SPDX-License-Identifier: Apache-2.0
// Builds cluster inputs in a MemoryImage for the engine tests.
#pragma once

#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/memory_image.h"

#include <cstring>
#include <random>
#include <vector>

namespace clastrace::engine::test {

// A bump allocator over one big region, so tests place buffers at known addresses.
struct Arena {
    MemoryImage memory;
    uint64_t base = 0x10000000;
    uint64_t next = 0x10000000;
    uint64_t size = 1 << 22;
    Arena() { memory.add_region(base, size, 0, "arena"); }
    uint64_t alloc(uint64_t bytes, uint64_t align = 256) {
        next = (next + align - 1) & ~(align - 1);
        const uint64_t a = next;
        next += bytes;
        return a;
    }
    uint64_t put(const void* data, uint64_t bytes, uint64_t align = 256) {
        const uint64_t a = alloc(bytes, align);
        std::memcpy(memory.write_bytes(a, bytes, {"test", -1}).data(), data, bytes);
        return a;
    }
    template <class T>
    uint64_t put_vec(const std::vector<T>& v, uint64_t align = 256) {
        return put(v.data(), v.size() * sizeof(T), align);
    }
};

inline VkClusterAccelerationStructureTriangleClusterInputNV default_input(
    VkFormat format = VK_FORMAT_R32G32B32_SFLOAT) {
    VkClusterAccelerationStructureTriangleClusterInputNV in{};
    in.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    in.vertexFormat = format;
    in.maxGeometryIndexValue = 1000;
    in.maxClusterUniqueGeometryCount = 8;
    in.maxClusterTriangleCount = 256;
    in.maxClusterVertexCount = 256;
    in.maxTotalTriangleCount = 1 << 20;
    in.maxTotalVertexCount = 1 << 20;
    in.minPositionTruncateBitCount = 0;
    return in;
}

// A grid mesh of (n+1)^2 vertices and 2n^2 triangles in the z = `z` plane, jittered.
struct Mesh {
    std::vector<float> positions;
    std::vector<uint32_t> indices;
};
inline Mesh grid(uint32_t n, float scale = 1.0f, uint32_t seed = 1, float z = 0.0f) {
    Mesh m;
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> j(-0.2f, 0.2f);
    for (uint32_t y = 0; y <= n; ++y)
        for (uint32_t x = 0; x <= n; ++x) {
            m.positions.push_back((float(x) + (x && x < n ? j(rng) : 0.0f)) * scale);
            m.positions.push_back((float(y) + (y && y < n ? j(rng) : 0.0f)) * scale);
            m.positions.push_back(z + j(rng) * scale);
        }
    for (uint32_t y = 0; y < n; ++y)
        for (uint32_t x = 0; x < n; ++x) {
            const uint32_t a = y * (n + 1) + x, b = a + 1, c = a + n + 1, d = c + 1;
            m.indices.insert(m.indices.end(), {a, b, d, a, d, c});
        }
    return m;
}

inline VkClusterAccelerationStructureBuildTriangleClusterInfoNV cluster_info(
    Arena& arena, const Mesh& m, uint32_t cluster_id = 7) {
    VkClusterAccelerationStructureBuildTriangleClusterInfoNV info{};
    info.clusterID = cluster_id;
    info.triangleCount = uint32_t(m.indices.size() / 3);
    info.vertexCount = uint32_t(m.positions.size() / 3);
    info.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
    info.indexBuffer = arena.put_vec(m.indices);
    info.vertexBuffer = arena.put_vec(m.positions);
    info.indexBufferStride = 4;
    info.vertexBufferStride = 12;
    return info;
}

}  // namespace clastrace::engine::test
