// SPDX-License-Identifier: Apache-2.0
// Test scenes for the NV engine: a MemoryImage with buffers, BLAS/TLAS built through
// engine::execute_nv_build, the same scene in Embree 3 (instances of per-BLAS scenes,
// user geometry for AABBs, filter functions for Vulkan's mask/facing/opacity rules), and
// the agreement classes of tests/engine_clas.
#pragma once

#include <clastrace/engine/nv_build.h>
#include <clastrace/engine/nv_trace.h>
#include <clastrace/testsupport/mesh.h>

#include <embree3/rtcore.h>

#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

namespace clastrace::nvtest {

namespace eng = clastrace::engine;
namespace ts = clastrace::testsupport;

struct GeometrySpec {
    ts::TriangleMesh mesh;                    // triangles (positions are object space)
    std::vector<std::array<float, 6>> boxes;  // AABBs (min xyz, max xyz) when aabbs
    uint32_t flags = VK_GEOMETRY_OPAQUE_BIT_NV;
};
struct BlasSpec {
    bool aabbs = false;
    std::vector<GeometrySpec> geometries;
};
struct InstanceSpec {
    float transform[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    uint32_t custom_index = 0;  // 24 bits
    uint32_t mask = 0xFF;
    uint32_t sbt_offset = 0;
    uint32_t flags = 0;  // VkGeometryInstanceFlagsNV
    int blas = 0;        // index into the BLAS list; -1: reference 0 (inactive)
};

// A device address space with bump-allocated buffers (256-aligned, gaps between them).
struct NvWorld {
    eng::MemoryImage memory;
    uint64_t next = 0x100000;
    uint64_t alloc(uint64_t size, const std::string& label);
    uint64_t put(const void* data, uint64_t size, const std::string& label);
    // An object with memory of the engine's requirement for `info`; handle = address.
    eng::NvObjectBinding make_object(const eng::NvObjectInfo& info, const std::string& label);
    uint64_t scratch(uint64_t size);

    // Writes the BLAS inputs (R32G32B32 vertices, UINT32 indices) and returns the info.
    eng::NvObjectInfo blas_info(const BlasSpec& spec,
                                VkBuildAccelerationStructureFlagsNV flags = 0);
    std::vector<uint8_t> instance_bytes(const std::vector<InstanceSpec>& instances,
                                        const std::vector<uint64_t>& handles) const;

    eng::ExecutionRecord build(const eng::NvObjectInfo& info, eng::NvObjectBinding& dst,
                               uint64_t instance_address = 0, bool update = false,
                               const eng::NvObjectBinding* src = nullptr,
                               const eng::NvBuildOptions& options = {});
};

// Builds every BLAS and the TLAS of a scene; objects' handles are their addresses.
struct BuiltScene {
    NvWorld world;
    std::vector<eng::NvObjectBinding> blas;
    eng::NvObjectBinding tlas;
    uint64_t instance_address = 0;
    std::vector<std::string> findings;  // every finding of every build, "rule: message"
};
std::unique_ptr<BuiltScene> build_scene(const std::vector<BlasSpec>& blas,
                                        const std::vector<InstanceSpec>& instances,
                                        VkBuildAccelerationStructureFlagsNV flags = 0);

struct RefHit {
    bool hit = false;
    float t = 0;
    uint32_t instance = 0, custom_index = 0, geometry = 0, primitive = 0, hit_kind = 0;
    float u = 0, v = 0;
};

// The same scene in Embree 3.
class EmbreeNvScene {
public:
    EmbreeNvScene(const std::vector<BlasSpec>& blas, const std::vector<InstanceSpec>& instances);
    ~EmbreeNvScene();
    EmbreeNvScene(const EmbreeNvScene&) = delete;
    EmbreeNvScene& operator=(const EmbreeNvScene&) = delete;
    RefHit closest(const eng::Ray& ray, uint32_t ray_flags, uint32_t cull_mask) const;
    bool any(const eng::Ray& ray, uint32_t ray_flags, uint32_t cull_mask) const;

    struct Geometry;
    struct Instance {
        InstanceSpec spec;
        double inverse[12];
    };

private:
    RTCDevice device_ = nullptr;
    RTCScene top_ = nullptr;
    std::vector<RTCScene> blas_;
    std::vector<std::unique_ptr<Geometry>> geometries_;
    std::vector<Instance> instances_;
};

struct Agreement {
    size_t rays = 0, agree_miss = 0, agree_hit = 0;
    size_t tie = 0;   // different primitive at the same t (shared edges, coplanar overlaps)
    size_t edge = 0;  // hit/miss or primitive differs, and the hit lies within 1e-5 of an edge
    size_t disagree = 0;
    size_t any_agree = 0, any_disagree = 0;
    double max_rel_t = 0;
    std::vector<std::string> examples;
    std::string summary() const;
};
void classify(Agreement& a, const eng::NvHit& engine, const RefHit& ref, double rel_t_tolerance,
              const std::string& what);

// Every ray-flag set that changes the answer, in the order the agreement runs cycle them.
inline constexpr uint32_t kAnswerChangingRayFlags[] = {0,
                                                       eng::kRayFlagOpaque,
                                                       eng::kRayFlagNoOpaque,
                                                       eng::kRayFlagCullBackFacingTriangles,
                                                       eng::kRayFlagCullFrontFacingTriangles,
                                                       eng::kRayFlagCullOpaque,
                                                       eng::kRayFlagCullNoOpaque,
                                                       eng::kRayFlagCullBackFacingTriangles |
                                                           eng::kRayFlagNoOpaque};

// Traces `ray_count` random rays inside [-extent, extent]^3 through the engine's scene and
// Embree's, origins and intervals times `ray_scale` (directions stay unit): ray i takes flag
// set i mod |flag_sets|, every third a random cull mask, every fourth an any-hit query too.
Agreement compare_with_embree(const eng::NvScene& scene, const EmbreeNvScene& embree,
                              size_t ray_count, float extent, uint64_t seed,
                              std::span<const uint32_t> flag_sets = kAnswerChangingRayFlags,
                              float ray_scale = 1.0f);

// What the agreement tests ask of a run: the examples reported as failures, no closest-hit or
// any-hit disagreement, few ties and edge cases, and at least rays / hit_divisor agreed hits
// and rays / miss_divisor agreed misses (0: not checked), so the scene was really reached.
struct AgreementFloor {
    size_t hit_divisor = 5;
    size_t miss_divisor = 20;
};
void expect_agreement(const Agreement& a, const std::string& what, AgreementFloor floor = {});

// Instances with random rotations, scales (some mirrored), translations, masks, custom
// indices and flags over `blas_count` BLAS, spread inside [-extent, extent]^3.
std::vector<InstanceSpec> random_instances(size_t count, int blas_count, float extent,
                                           uint64_t seed);
// Random boxes inside [-1, 1]^3.
std::vector<std::array<float, 6>> random_boxes(size_t count, uint64_t seed);

}  // namespace clastrace::nvtest
