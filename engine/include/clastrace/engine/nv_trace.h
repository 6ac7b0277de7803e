// SPDX-License-Identifier: Apache-2.0
// Ray traversal of NV objects: top level -> instance transform -> bottom level. A top level
// (NV or KHR: the same objects, khr_build.h) may name a cluster BLAS (blas.h) too: one
// traversal entry per instance dispatches on the object's kind, and a cluster BLAS is
// traced through its CLAS (the instance flags put into the ray's flags).
//
// Vulkan's rules as the engine applies them (no shaders run):
// - An instance is visited when (mask & cullMask & 0xFF) != 0 and it is active (reference
//   not 0, its BLAS found when the TLAS was built and still a bottom-level object now).
// - The ray enters the BLAS through the inverse of the instance's 3x4 transform (double
//   precision; TraversalMode::kFloat32: that inverse rounded to float, applied in float);
//   t is the same parameter in both spaces (the direction is not normalized).
// - Triangles: watertight test (Woop, Benthin & Wald 2013) in the mode's precision. Facing is
//   decided in object space: front-facing when dot(direction, cross(v1 - v0, v2 - v0)) < 0,
//   inverted by the instance flag TRIANGLE_FRONT_COUNTERCLOCKWISE (FLIP_FACING). Culling by
//   the ray flags CullBack/CullFrontFacing unless the instance has TRIANGLE_CULL_DISABLE.
//   Hit kind 0xFE front, 0xFF back; u, v are the weights of v1 and v2.
// - Opacity: the geometry's OPAQUE flag, overridden by the instance's FORCE_OPAQUE /
//   FORCE_NO_OPAQUE, overridden by the ray's Opaque / NoOpaque; then CullOpaque /
//   CullNoOpaque. A non-opaque candidate is accepted (as by an any-hit shader that
//   does not ignore it).
// - AABBs: the engine stands in for the intersection shader: it reports the box entry
//   (max(t_entry, tmin); tmin when the origin is inside), hit kind 0, u = v = 0;
//   kFloat32 evaluates it as the ray check's shader does, in float without widening.
// - Closest hit: the smallest t; on equal t the lowest (instance, geometry, primitive) index,
//   whatever order the traversal visits them in. TerminateOnFirstHit: the first accepted hit.
#pragma once

#include "clastrace/engine/finding.h"
#include "clastrace/engine/memory_image.h"
#include "clastrace/engine/nv_format.h"
#include "clastrace/engine/traversal.h"

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace clastrace::engine {

inline constexpr uint32_t kHitKindFrontFacing = 0xFE;
inline constexpr uint32_t kHitKindBackFacing = 0xFF;

struct NvHit {
    bool hit = false;
    float t = 0.0f;
    uint32_t instance_index = 0;         // gl_InstanceID: index of the instance record
    uint32_t instance_custom_index = 0;  // gl_InstanceCustomIndexEXT
    uint32_t sbt_offset = 0;
    uint32_t geometry_index = 0;
    uint32_t primitive_index = 0;       // gl_PrimitiveID
    uint32_t cluster_id = 0xFFFFFFFFu;  // a cluster BLAS's hit: the CLAS's clusterID; else ~0
    float u = 0.0f, v = 0.0f;
    uint32_t hit_kind = 0;
    bool opaque = false;
    // How far a float32 implementation's t may honestly sit from this t: a few units in the
    // last place of the largest coordinate the hit involved (the primitive's object-space
    // coordinates, the ray origin and its transform into object space), divided by the
    // direction's size. Drivers trace in float; the engine in double. Replay compares a
    // driver's t against this bound, not only against a relative tolerance of t.
    float t_error = 0.0f;
    // How far a float32 implementation's u, v may sit from these (Hit::uv_error).
    float uv_error = 0.0f;
};

// A top-level object opened once for many rays: its bytes and every BLAS it reaches are
// copied and checked (open_nv_object), so tracing never touches memory again, and their trees
// laid out for traversal (4-wide nodes; docs/engine-nv-formats.md, "The traversal's layout").
class NvScene {
public:
    // The scene of the top-level object at `address`; nullopt with `error` when the bytes
    // there are no checked NV top-level object. Instances whose BLAS is gone or damaged are
    // left out, each with a finding.
    static std::optional<NvScene> open(const MemoryImage& memory, uint64_t address,
                                       std::vector<Finding>* findings, std::string* error);
    // One bottom-level object as the scene of one instance (identity transform, mask 0xFF,
    // instance index 0, custom index 0, flags 0).
    static std::optional<NvScene> open_bottom(const MemoryImage& memory, uint64_t address,
                                              std::string* error);

    NvHit closest(const Ray& ray, uint32_t ray_flags, uint32_t cull_mask,
                  TraversalMode mode = TraversalMode::kDouble) const;
    bool any(const Ray& ray, uint32_t ray_flags, uint32_t cull_mask,
             TraversalMode mode = TraversalMode::kDouble) const;
    // closest() without any box: every primitive of every reached instance is tested. The
    // plain answer the trees' traversal must equal exactly (tests; far slower).
    NvHit closest_exhaustive(const Ray& ray, uint32_t ray_flags, uint32_t cull_mask,
                             TraversalMode mode = TraversalMode::kDouble) const;

    uint32_t instance_count() const;
    uint32_t instances_reached() const;  // instances with a usable BLAS
    // Bytes the scene keeps for tracing NV bottom levels and its top level: the copied
    // primitive records and nodes, and the traversal's 4-wide nodes
    // (docs/engine-nv-formats.md, "The traversal's layout"); `wide_nodes` their count.
    uint64_t traversal_bytes(uint64_t* wide_nodes = nullptr) const;

    struct Data;
    NvScene(std::shared_ptr<const Data> data) : data_(std::move(data)) {}

private:
    std::shared_ptr<const Data> data_;
};

inline constexpr const char* kRuleNvStaleInstance = "CLASTRACE-nv-instance-blas-gone";

}  // namespace clastrace::engine
