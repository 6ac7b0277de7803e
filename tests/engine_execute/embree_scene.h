// SPDX-License-Identifier: Apache-2.0
// Embree as the reference: one BVH over every triangle of a clustered mesh.
#pragma once

#include "execute_rig.h"

#include <clastrace/testsupport/embree_reference.h>

#include <cstdio>
#include <cstring>

namespace clastrace::engine::execute_test {

// Embree's BVH over every triangle of the mesh (one geometry: primID = the mesh's triangle).
class EmbreeScene {
public:
    EmbreeScene(const std::vector<float>& positions, const std::vector<uint32_t>& indices)
        : ref_(/*robust=*/false) {
        std::vector<testsupport::Float3> p(positions.size() / 3);
        std::vector<testsupport::Triangle> t(indices.size() / 3);
        std::memcpy(p.data(), positions.data(), p.size() * sizeof p[0]);
        std::memcpy(t.data(), indices.data(), t.size() * sizeof t[0]);
        ref_.add_cluster(p, t);
        ref_.commit();
    }
    testsupport::ReferenceHit trace(const Ray& r) const {
        return ref_.intersect(testsupport::TestRay{{r.origin[0], r.origin[1], r.origin[2]},
                                                   r.tmin,
                                                   {r.direction[0], r.direction[1], r.direction[2]},
                                                   r.tmax});
    }

private:
    testsupport::EmbreeReference ref_;
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
inline void expect_matches_embree(const Rig& rig, uint64_t blas, const ClusteredMesh& m,
                                  uint32_t id_base = 0, const ObjectDirectory* dir = nullptr) {
    EmbreeScene ref(m.positions, m.indices);
    auto rays = sphere_rays(4000, 7);
    size_t hits = 0, primitive_mismatch = 0;
    std::vector<Finding> findings;
    for (const Ray& r : rays) {
        BottomLevelHit ours = trace_bottom_level_closest(rig.memory, blas, r, 0, dir, &findings);
        const testsupport::ReferenceHit theirs = ref.trace(r);
        const bool they_hit = theirs.hit;
        ASSERT_EQ(ours.hit.hit, they_hit)
            << "ray origin " << r.origin[0] << "," << r.origin[1] << "," << r.origin[2];
        if (!they_hit) continue;
        ++hits;
        EXPECT_NEAR(ours.hit.t, theirs.t, 1e-5f * std::max(1.0f, theirs.t));
        uint32_t cluster = ours.hit.cluster_id - id_base;
        ASSERT_LT(cluster, m.clusters.size());
        ASSERT_LT(ours.hit.triangle_index, m.cluster_triangle_to_global[cluster].size());
        uint32_t global = m.cluster_triangle_to_global[cluster][ours.hit.triangle_index];
        if (global != theirs.triangle) {
            ++primitive_mismatch;  // a ray through a shared edge: either neighbour is right
        } else {
            EXPECT_NEAR(ours.hit.u, theirs.u, 1e-4f);
            EXPECT_NEAR(ours.hit.v, theirs.v, 1e-4f);
        }
    }
    EXPECT_TRUE(findings.empty()) << describe(findings);
    std::printf("  %zu rays, %zu hits, %zu hit another triangle at the same t (shared edge)\n",
                rays.size(), hits, primitive_mismatch);
    EXPECT_GT(hits, rays.size() / 2);
    EXPECT_LE(primitive_mismatch, hits / 500) << primitive_mismatch << " of " << hits;
}

}  // namespace clastrace::engine::execute_test
