// SPDX-License-Identifier: Apache-2.0
// A device memory layout and a meshlet-clustered procedural mesh for the engine::execute tests.
#pragma once

#include "clastrace/engine/blas.h"
#include "clastrace/engine/build_sizes.h"
#include "clastrace/engine/execute.h"
#include "clastrace/engine/memory_image.h"

#include <gtest/gtest.h>
#include <meshoptimizer.h>

#include <array>
#include <cmath>
#include <cstring>
#include <map>
#include <random>
#include <string>
#include <vector>

namespace clastrace::engine::execute_test {

// Separate regions, so a test can aim an address at one kind of memory.
struct Rig {
    MemoryImage memory;
    struct Bump {
        uint64_t base, next, size;
    };
    Bump inputs{0x100000000ull, 0x100000000ull, 0};
    Bump objects{0x200000000ull, 0x200000000ull, 0};
    Bump objects2{0x300000000ull, 0x300000000ull, 0};
    Bump scratch{0x400000000ull, 0x400000000ull, 0};
    Bump arrays{0x500000000ull, 0x500000000ull, 0};
    explicit Rig(uint64_t mib = 8) {
        for (Bump* b : {&inputs, &objects, &objects2, &arrays}) b->size = mib << 20;
        scratch.size = 1 << 20;
        memory.add_region(inputs.base, inputs.size, 0, "inputs");
        memory.add_region(objects.base, objects.size, 0, "objects");
        memory.add_region(objects2.base, objects2.size, 0, "objects2");
        memory.add_region(scratch.base, scratch.size, 0, "scratch");
        memory.add_region(arrays.base, arrays.size, 0, "arrays");
    }
    static uint64_t alloc(Bump& b, uint64_t bytes, uint64_t align = 256) {
        b.next = (b.next + align - 1) / align * align;
        uint64_t a = b.next;
        b.next += bytes;
        if (b.next > b.base + b.size) throw std::runtime_error("test rig region full");
        return a;
    }
    uint64_t put(Bump& b, const void* data, uint64_t bytes, uint64_t align = 256) {
        uint64_t a = alloc(b, bytes, align);
        if (bytes) std::memcpy(memory.write_bytes(a, bytes, {"test", -1}).data(), data, bytes);
        return a;
    }
    template <class T>
    uint64_t put_vec(Bump& b, const std::vector<T>& v, uint64_t align = 256) {
        return put(b, v.data(), v.size() * sizeof(T), align);
    }
    template <class T>
    T get(uint64_t address) const {
        return memory.read<T>(address, {"test", -1});
    }
    std::vector<std::byte> bytes(uint64_t address, uint64_t size) const {
        auto s = memory.read_bytes(address, size, {"test", -1});
        return {s.begin(), s.end()};
    }
    // All bytes of all regions, for determinism and "touches nothing" checks.
    std::map<uint64_t, std::vector<std::byte>> snapshot() const {
        std::map<uint64_t, std::vector<std::byte>> s;
        for (const auto& [base, r] : memory.regions()) s[base] = r.bytes;
        return s;
    }
};

struct Cluster {
    std::vector<float> positions;    // xyz per local vertex
    std::vector<uint8_t> triangles;  // 3 local indices per triangle
};

// An icosphere subdivided `levels` times (20 * 4^levels triangles), cut into meshlets by
// meshoptimizer: what a clustered-geometry renderer feeds the extension.
struct ClusteredMesh {
    std::vector<float> positions;
    std::vector<uint32_t> indices;
    std::vector<Cluster> clusters;
    std::vector<std::vector<uint32_t>>
        cluster_triangle_to_global;  // per cluster: global triangle index
};

inline ClusteredMesh icosphere_meshlets(int levels, float radius = 1.0f, size_t max_vertices = 64,
                                        size_t max_triangles = 124) {
    ClusteredMesh m;
    const float t = (1.0f + std::sqrt(5.0f)) / 2.0f;
    std::vector<std::array<float, 3>> v = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0},
                                           {0, -1, t}, {0, 1, t}, {0, -1, -t}, {0, 1, -t},
                                           {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
    std::vector<std::array<uint32_t, 3>> f = {{0, 11, 5},  {0, 5, 1},  {0, 1, 7},  {0, 7, 10},
                                              {0, 10, 11}, {1, 5, 9},  {5, 11, 4}, {11, 10, 2},
                                              {10, 7, 6},  {7, 1, 8},  {3, 9, 4},  {3, 4, 2},
                                              {3, 2, 6},   {3, 6, 8},  {3, 8, 9},  {4, 9, 5},
                                              {2, 4, 11},  {6, 2, 10}, {8, 6, 7},  {9, 8, 1}};
    for (int l = 0; l < levels; ++l) {
        std::map<std::pair<uint32_t, uint32_t>, uint32_t> mid;
        auto midpoint = [&](uint32_t a, uint32_t b) {
            auto key = std::minmax(a, b);
            auto it = mid.find(key);
            if (it != mid.end()) return it->second;
            std::array<float, 3> p{(v[a][0] + v[b][0]) / 2, (v[a][1] + v[b][1]) / 2,
                                   (v[a][2] + v[b][2]) / 2};
            v.push_back(p);
            return mid[key] = uint32_t(v.size() - 1);
        };
        std::vector<std::array<uint32_t, 3>> g;
        for (auto& tri : f) {
            uint32_t a = midpoint(tri[0], tri[1]), b = midpoint(tri[1], tri[2]),
                     c = midpoint(tri[2], tri[0]);
            g.insert(g.end(), {{tri[0], a, c}, {tri[1], b, a}, {tri[2], c, b}, {a, b, c}});
        }
        f = std::move(g);
    }
    for (auto& p : v) {
        float len = std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
        for (float c : p) m.positions.push_back(c / len * radius);
    }
    for (auto& tri : f) m.indices.insert(m.indices.end(), tri.begin(), tri.end());
    size_t bound = meshopt_buildMeshletsBound(m.indices.size(), max_vertices, max_triangles);
    std::vector<meshopt_Meshlet> meshlets(bound);
    std::vector<unsigned int> mv(bound * max_vertices);
    std::vector<unsigned char> mt(bound * max_triangles * 3);
    size_t count =
        meshopt_buildMeshlets(meshlets.data(), mv.data(), mt.data(), m.indices.data(),
                              m.indices.size(), m.positions.data(), m.positions.size() / 3, 12,
                              max_vertices, max_triangles, 0.0f);
    // Map each meshlet triangle back to the global triangle (by its vertex set).
    std::map<std::array<uint32_t, 3>, uint32_t> global;
    for (uint32_t i = 0; i < f.size(); ++i) {
        auto k = f[i];
        std::sort(k.begin(), k.end());
        global[k] = i;
    }
    for (size_t c = 0; c < count; ++c) {
        const meshopt_Meshlet& ml = meshlets[c];
        Cluster cl;
        std::vector<uint32_t> map;
        for (uint32_t i = 0; i < ml.vertex_count; ++i)
            for (int a = 0; a < 3; ++a)
                cl.positions.push_back(m.positions[3 * mv[ml.vertex_offset + i] + a]);
        for (uint32_t i = 0; i < ml.triangle_count * 3; ++i)
            cl.triangles.push_back(mt[ml.triangle_offset + i]);
        for (uint32_t i = 0; i < ml.triangle_count; ++i) {
            std::array<uint32_t, 3> k{mv[ml.vertex_offset + cl.triangles[3 * i]],
                                      mv[ml.vertex_offset + cl.triangles[3 * i + 1]],
                                      mv[ml.vertex_offset + cl.triangles[3 * i + 2]]};
            std::sort(k.begin(), k.end());
            map.push_back(global.at(k));
        }
        m.clusters.push_back(std::move(cl));
        m.cluster_triangle_to_global.push_back(std::move(map));
    }
    return m;
}

inline VkClusterAccelerationStructureTriangleClusterInputNV triangle_input(
    uint32_t max_count_hint = 1u << 20) {
    VkClusterAccelerationStructureTriangleClusterInputNV in{};
    in.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    in.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    in.maxGeometryIndexValue = 16;
    in.maxClusterUniqueGeometryCount = 1;
    in.maxClusterTriangleCount = 128;
    in.maxClusterVertexCount = 128;
    in.maxTotalTriangleCount = max_count_hint;
    in.maxTotalVertexCount = max_count_hint;
    return in;
}

// Uploads the clusters' buffers and their VkClusterAccelerationStructureBuildTriangleClusterInfoNV
// (clusterID = cluster index, 8-bit indices); returns the infos array address.
inline uint64_t upload_cluster_infos(Rig& rig, const ClusteredMesh& m, bool as_templates = false,
                                     uint32_t id_base = 0) {
    std::vector<std::byte> infos;
    for (size_t c = 0; c < m.clusters.size(); ++c) {
        const Cluster& cl = m.clusters[c];
        VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV info{};
        info.clusterID = uint32_t(c) + id_base;
        info.triangleCount = uint32_t(cl.triangles.size() / 3);
        info.vertexCount = uint32_t(cl.positions.size() / 3);
        info.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV;
        info.indexBufferStride = 1;
        info.vertexBufferStride = 12;
        info.indexBuffer = rig.put_vec(rig.inputs, cl.triangles, 16);
        info.vertexBuffer = rig.put_vec(rig.inputs, cl.positions, 16);
        size_t size = as_templates
                          ? sizeof(VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV)
                          : sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);
        const std::byte* p = reinterpret_cast<const std::byte*>(&info);
        infos.insert(infos.end(), p, p + size);
    }
    return rig.put_vec(rig.inputs, infos, 16);
}

// The command for `count` ops whose src infos start at `src_infos` (packed).
struct CommandSetup {
    VkClusterAccelerationStructureCommandsInfoNV cmd{};
    VkClusterAccelerationStructureTriangleClusterInputNV triangles{};
    VkClusterAccelerationStructureClustersBottomLevelInputNV bottom{};
    VkClusterAccelerationStructureMoveObjectsInputNV move{};
    CommandSetup() = default;
    CommandSetup(const CommandSetup&) = delete;  // cmd points into this object
};

inline void setup_command(CommandSetup& s, Rig& rig, VkClusterAccelerationStructureOpTypeNV type,
                          VkClusterAccelerationStructureOpModeNV mode, uint32_t count,
                          uint64_t src_infos) {
    auto& c = s.cmd;
    c.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    c.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    c.input.maxAccelerationStructureCount = count;
    c.input.opType = type;
    c.input.opMode = mode;
    if (type == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV) {
        s.move.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_MOVE_OBJECTS_INPUT_NV;
        s.move.type = VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV;
        s.move.maxMovedBytes = 64ull << 20;
        c.input.opInput.pMoveObjects = &s.move;
    } else if (type == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV) {
        s.bottom.sType =
            VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV;
        s.bottom.maxTotalClusterCount = 1u << 20;
        s.bottom.maxClusterCountPerAccelerationStructure = 1u << 20;
        c.input.opInput.pClustersBottomLevel = &s.bottom;
    } else {
        s.triangles = triangle_input();
        c.input.opInput.pTriangleClusters = &s.triangles;
    }
    c.srcInfosArray = {src_infos, 0, 0};
    c.scratchData = Rig::alloc(rig.scratch, std::max<uint64_t>(16, 16ull * count), 256);
    if (mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV) {
        c.dstImplicitData = Rig::alloc(rig.objects, 0, 256);
        c.dstAddressesArray = {Rig::alloc(rig.arrays, 8ull * count, 8), 8, 8ull * count};
    }
    if (mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV)
        c.dstAddressesArray = {Rig::alloc(rig.arrays, 8ull * count, 8), 8, 8ull * count};
    c.dstSizesArray = {Rig::alloc(rig.arrays, 4ull * count, 4), 4, 4ull * count};
}

// After an implicit command: reserve what it packed so later allocations do not overlap.
inline void claim_implicit(Rig& rig, const ExecutionRecord& r) {
    rig.objects.next += r.implicit_bytes_used;
}

inline std::vector<uint64_t> dst_addresses(const Rig& rig,
                                           const VkClusterAccelerationStructureCommandsInfoNV& c,
                                           uint32_t count) {
    std::vector<uint64_t> a;
    for (uint32_t i = 0; i < count; ++i)
        a.push_back(rig.get<uint64_t>(c.dstAddressesArray.deviceAddress + 8ull * i));
    return a;
}

inline std::string describe(const std::vector<Finding>& f) {
    std::string s;
    for (const auto& x : f) s += x.rule + ": " + x.message + "\n";
    return s;
}

inline size_t count_rule(const std::vector<Finding>& f, const std::string& rule) {
    size_t n = 0;
    for (const auto& x : f) n += x.rule == rule;
    return n;
}

// Builds every cluster of `m` as CLAS, implicitly; returns their addresses.
inline std::vector<uint64_t> build_clas(Rig& rig, const ClusteredMesh& m,
                                        ObjectDirectory* dir = nullptr) {
    uint64_t infos = upload_cluster_infos(rig, m);
    CommandSetup s;
    setup_command(s, rig, VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV,
                  VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV,
                  uint32_t(m.clusters.size()), infos);
    ExecuteOptions o;
    o.directory = dir;
    ExecutionRecord r = execute(s.cmd, rig.memory, o);
    EXPECT_TRUE(r.findings.empty()) << describe(r.findings);
    claim_implicit(rig, r);
    return dst_addresses(rig, s.cmd, uint32_t(m.clusters.size()));
}

// Writes the reference array and the BLAS info; returns the info's address.
inline uint64_t upload_blas_info(Rig& rig, const std::vector<uint64_t>& clas, uint32_t stride = 8) {
    std::vector<std::byte> refs(clas.size() * stride);
    for (size_t i = 0; i < clas.size(); ++i) std::memcpy(refs.data() + i * stride, &clas[i], 8);
    VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV info{};
    info.clusterReferencesCount = uint32_t(clas.size());
    info.clusterReferencesStride = stride;
    info.clusterReferences = rig.put_vec(rig.inputs, refs, 8);
    return rig.put(rig.inputs, &info, sizeof info, 16);
}

inline uint64_t build_blas(Rig& rig, const std::vector<uint64_t>& clas,
                           ObjectDirectory* dir = nullptr,
                           std::vector<Finding>* findings = nullptr) {
    uint64_t info = upload_blas_info(rig, clas);
    CommandSetup s;
    setup_command(s, rig, VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV,
                  VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV, 1, info);
    ExecuteOptions o;
    o.directory = dir;
    ExecutionRecord r = execute(s.cmd, rig.memory, o);
    if (findings)
        *findings = r.findings;
    else
        EXPECT_TRUE(r.findings.empty()) << describe(r.findings);
    claim_implicit(rig, r);
    return rig.get<uint64_t>(s.cmd.dstAddressesArray.deviceAddress);
}

}  // namespace clastrace::engine::execute_test
