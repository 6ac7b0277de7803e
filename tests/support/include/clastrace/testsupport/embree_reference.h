// SPDX-License-Identifier: Apache-2.0
// Embree 3 as the reference tracer: one geometry per cluster (geomID = cluster index,
// primID = triangle index inside the cluster), built from exactly the float positions the
// CLAS holds after truncation.
#pragma once

#include "clastrace/testsupport/mesh.h"
#include "clastrace/testsupport/rays.h"

#include <embree3/rtcore.h>

#include <span>
#include <string>

namespace clastrace::testsupport {

struct ReferenceHit {
    bool hit = false;
    float t = 0, u = 0, v = 0;
    uint32_t cluster = 0, triangle = 0;
};

// One device per process, created on first use ("threads=N" when a count is given).
RTCDevice embree_device();
RTCDevice make_embree_device(const std::string& config);

class EmbreeReference {
public:
    // robust = RTC_SCENE_FLAG_ROBUST (watertight, the mode to compare a watertight tracer against).
    explicit EmbreeReference(bool robust, RTCDevice device = embree_device(),
                             RTCBuildQuality quality = RTC_BUILD_QUALITY_MEDIUM);
    ~EmbreeReference();
    EmbreeReference(const EmbreeReference&) = delete;
    EmbreeReference& operator=(const EmbreeReference&) = delete;

    // Copies the positions; returns the geometry id (== the number of clusters added before).
    uint32_t add_cluster(std::span<const Float3> positions, std::span<const Triangle> triangles);
    void commit();

    ReferenceHit intersect(const TestRay& ray) const;
    bool occluded(const TestRay& ray) const;
    // Every triangle the ray meets with t in [t*(1-rel), t*(1+rel)] (plus an absolute floor):
    // more than one entry means Embree itself has a tie at t.
    std::vector<ReferenceHit> hits_near(const TestRay& ray, float t, float rel) const;

private:
    RTCScene scene_ = nullptr;
    RTCBuildQuality quality_;
    uint32_t count_ = 0;
};

}  // namespace clastrace::testsupport
