// SPDX-License-Identifier: Apache-2.0
// A mesh's clusters written into a MemoryImage the way an application fills its build-input
// buffers, built into CLAS objects by the engine, and traced as one scene (every cluster's
// AABB tested, the closest hit kept): the engine side of the Embree comparison.
#pragma once

#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/memory_image.h"
#include "clastrace/testsupport/clusters.h"
#include "clastrace/testsupport/embree_reference.h"
#include "clastrace/testsupport/rays.h"

namespace clastrace::testsupport {

struct ClusterInputLayout {
    uint32_t index_bytes = 1;    // 1, 2 or 4 (indexType 8/16/32 bit)
    uint16_t index_stride = 0;   // bytes, 0 = packed
    uint16_t vertex_stride = 0;  // bytes, 0 = packed (12)
    uint32_t truncate_bits = 0;
};

struct ClusterSceneInputs {
    engine::MemoryImage memory;
    VkClusterAccelerationStructureTriangleClusterInputNV input{};
    std::vector<VkClusterAccelerationStructureBuildTriangleClusterInfoNV> infos;  // one per cluster
};

// Addresses: vertex data from 0x1000'0000, index data from 0x8000'0000 (one region each);
// the bytes between strided elements hold 0xCD so a reader that ignores the stride shows.
ClusterSceneInputs write_cluster_inputs(const TriangleMesh& mesh,
                                        const std::vector<MeshCluster>& clusters,
                                        const ClusterInputLayout& layout);

struct ClusterScene {
    std::vector<std::vector<std::byte>>
        objects;  // one CLAS per cluster (clusterID = cluster index)
    std::vector<std::vector<engine::Finding>> findings;
    std::vector<Bounds> bounds;                    // of the truncated positions
    std::vector<std::vector<Float3>> positions;    // truncated, cluster-local (what Embree gets)
    std::vector<std::vector<Triangle>> triangles;  // cluster-local
    size_t failed_builds = 0;
};

ClusterScene build_cluster_scene(const TriangleMesh& mesh, const std::vector<MeshCluster>& clusters,
                                 const ClusterInputLayout& layout);

// The same truncated clusters as Embree geometry (geomID = cluster index).
void add_to_embree(const ClusterScene& scene, EmbreeReference& embree);

struct SceneHit {
    bool hit = false;
    float t = 0, u = 0, v = 0;
    uint32_t cluster = 0, triangle = 0;
};
// Closest hit over all clusters whose AABB the ray meets (ray flags 0: no culling).
SceneHit trace_scene(const ClusterScene& scene, const TestRay& ray);
// Whether any cluster reports a hit in [tmin, tmax] (trace_any, ray flags 0).
bool trace_scene_any(const ClusterScene& scene, const TestRay& ray);

// Embree's BVH over the cluster AABBs (user geometry) with the engine tracing inside each
// cluster: closest hits for scenes of thousands of clusters (benchmarks). The tests use the
// plain loop of trace_scene, so that no Embree code sits on the engine's side of a comparison.
class ClusterSceneTracer {
public:
    explicit ClusterSceneTracer(const ClusterScene& scene, RTCDevice device = embree_device());
    ~ClusterSceneTracer();
    ClusterSceneTracer(const ClusterSceneTracer&) = delete;
    ClusterSceneTracer& operator=(const ClusterSceneTracer&) = delete;
    SceneHit trace(const TestRay& ray) const;

private:
    const ClusterScene& scene_;
    RTCScene rtc_ = nullptr;
};

// How the engine and Embree agree on a ray set.
struct AgreementCounts {
    size_t rays = 0;
    size_t agree_miss = 0, agree_hit = 0;
    size_t tie = 0;  // different triangle, but Embree sees both at the same t
    // Embree's float result is the wrong one: a long-double evaluation of the same float
    // triangle (Moller-Trumbore, 64-bit mantissa) sides with the engine, clearly (its
    // barycentric margin or t error is far above long double's rounding).
    size_t embree_off = 0;
    size_t embree_off_t = 0, embree_off_hit_miss = 0, embree_off_prim = 0;  // its three kinds
    size_t disagree_hit_miss = 0, disagree_t = 0, disagree_prim = 0;
    double max_rel_t_error = 0;
    size_t disagreements() const { return disagree_hit_miss + disagree_t + disagree_prim; }
    std::string summary() const;
    std::vector<std::string> examples;  // first few disagreements, described
    std::vector<std::string> embree_off_examples;
};
AgreementCounts compare_with_embree(const ClusterScene& scene, const EmbreeReference& embree,
                                    const std::vector<TestRay>& rays,
                                    double rel_t_tolerance = 1e-6);

}  // namespace clastrace::testsupport
