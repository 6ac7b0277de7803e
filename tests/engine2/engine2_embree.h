// Embree as the reference: one BVH over every triangle of a clustered mesh.
#ifndef CLASTRACE_TESTS_ENGINE2_EMBREE_H
#define CLASTRACE_TESTS_ENGINE2_EMBREE_H

#include "engine2_test_util.h"

#include <embree3/rtcore.h>

#include <cstdio>

namespace clastrace::engine::test2 {

// One Embree BVH over every triangle of the mesh: the reference.
struct EmbreeScene {
  RTCDevice device = rtcNewDevice(nullptr);
  RTCScene scene = rtcNewScene(device);
  explicit EmbreeScene(const std::vector<float>& positions, const std::vector<uint32_t>& indices) {
    RTCGeometry g = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    float* v = static_cast<float*>(
        rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 12, positions.size() / 3));
    std::copy(positions.begin(), positions.end(), v);
    uint32_t* ix = static_cast<uint32_t*>(
        rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 12, indices.size() / 3));
    std::copy(indices.begin(), indices.end(), ix);
    rtcCommitGeometry(g);
    rtcAttachGeometry(scene, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(scene);
  }
  ~EmbreeScene() {
    rtcReleaseScene(scene);
    rtcReleaseDevice(device);
  }
  RTCRayHit trace(const Ray& r) const {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    RTCRayHit rh{};
    rh.ray.org_x = r.origin[0];
    rh.ray.org_y = r.origin[1];
    rh.ray.org_z = r.origin[2];
    rh.ray.dir_x = r.direction[0];
    rh.ray.dir_y = r.direction[1];
    rh.ray.dir_z = r.direction[2];
    rh.ray.tnear = r.tmin;
    rh.ray.tfar = r.tmax;
    rh.ray.mask = ~0u;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(scene, &ctx, &rh);
    return rh;
  }
};

inline std::vector<Ray> sphere_rays(uint32_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> g;
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<Ray> rays;
  for (uint32_t i = 0; i < n; ++i) {
    float o[3] = {g(rng), g(rng), g(rng)}, p[3] = {g(rng), g(rng), g(rng)};
    float lo = std::sqrt(o[0] * o[0] + o[1] * o[1] + o[2] * o[2]);
    float lp = std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
    Ray r{};
    float kind = u(rng);
    for (int a = 0; a < 3; ++a) {
      if (kind < 0.7f) {  // from outside toward a point inside: hits
        r.origin[a] = o[a] / lo * 3.0f;
        r.direction[a] = p[a] / lp * 0.9f * u(rng) - r.origin[a];
      } else if (kind < 0.9f) {  // from inside outward
        r.origin[a] = o[a] / lo * 0.5f * u(rng);
        r.direction[a] = p[a];
      } else {  // from outside, mostly away: many misses
        r.origin[a] = o[a] / lo * 3.0f;
        r.direction[a] = p[a];
      }
    }
    r.tmin = 0.0f;
    r.tmax = 1e30f;
    rays.push_back(r);
  }
  return rays;
}

// Traces every ray through the BLAS and Embree; returns the share of rays that disagree.
inline void expect_matches_embree(const Rig& rig, uint64_t blas, const ClusteredMesh& m, uint32_t id_base = 0,
                           const ObjectDirectory* dir = nullptr) {
  EmbreeScene ref(m.positions, m.indices);
  auto rays = sphere_rays(4000, 7);
  size_t hits = 0, primitive_mismatch = 0;
  std::vector<Finding> findings;
  for (const Ray& r : rays) {
    BottomLevelHit ours = trace_bottom_level_closest(rig.memory, blas, r, 0, dir, &findings);
    RTCRayHit theirs = ref.trace(r);
    bool they_hit = theirs.hit.geomID != RTC_INVALID_GEOMETRY_ID;
    ASSERT_EQ(ours.hit.hit, they_hit) << "ray origin " << r.origin[0] << "," << r.origin[1] << "," << r.origin[2];
    if (!they_hit) continue;
    ++hits;
    EXPECT_NEAR(ours.hit.t, theirs.ray.tfar, 1e-5f * std::max(1.0f, theirs.ray.tfar));
    uint32_t cluster = ours.hit.cluster_id - id_base;
    ASSERT_LT(cluster, m.clusters.size());
    ASSERT_LT(ours.hit.triangle_index, m.cluster_triangle_to_global[cluster].size());
    uint32_t global = m.cluster_triangle_to_global[cluster][ours.hit.triangle_index];
    if (global != theirs.hit.primID) {
      ++primitive_mismatch;  // a ray through a shared edge: either neighbour is right
    } else {
      EXPECT_NEAR(ours.hit.u, theirs.hit.u, 1e-4f);
      EXPECT_NEAR(ours.hit.v, theirs.hit.v, 1e-4f);
    }
  }
  EXPECT_TRUE(findings.empty()) << describe(findings);
  std::printf("  %zu rays, %zu hits, %zu hit another triangle at the same t (shared edge)\n", rays.size(), hits,
              primitive_mismatch);
  EXPECT_GT(hits, rays.size() / 2);
  EXPECT_LE(primitive_mismatch, hits / 500) << primitive_mismatch << " of " << hits;
}

}  // namespace clastrace::engine::test2

#endif
