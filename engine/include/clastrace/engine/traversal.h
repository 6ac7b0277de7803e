// SPDX-License-Identifier: Apache-2.0
// Ray queries against one CLAS, in the cluster's object space.
//
// Triangle test: watertight (Woop, Benthin & Wald 2013: dimension permutation, shear,
// edge functions), evaluated in double precision throughout so that coordinates up to
// ±FLT_MAX neither overflow nor lose the watertight property; rays through shared edges
// and vertices of a closed mesh always hit at least one triangle. Edge functions equal to
// zero count as inside (both neighbours may report the edge). BVH boxes use a
// conservative slab test (Ize 2013), so a box never culls a hit the triangle test finds.
//
// Hits are accepted when tmin <= t <= tmax (the Vulkan ray interval is closed).
// Triangles with a NaN coordinate, or with an index >= vertexCount, are inactive.
//
// Facing (Vulkan's default, no instance FLIP_FACING): a triangle is front-facing when
// its vertices v0, v1, v2 appear clockwise seen from the ray origin looking along the
// ray, in a left-handed frame; equivalently dot(direction, cross(v1 - v0, v2 - v0)) < 0.
//
// Opacity: a triangle is opaque when its geometry flags have
// VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_OPAQUE_BIT_NV, unless the ray flag Opaque
// (forces opaque) or NoOpaque (forces non-opaque) overrides it. The engine runs no
// any-hit shader: a non-opaque candidate that survives culling is accepted, as an
// any-hit shader that does not ignore it would. Opacity micromaps are not evaluated.
#pragma once

#include "clastrace/engine/cluster_format.h"

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>

namespace clastrace::engine {

// How a traversal rounds (docs/engine-nv-formats.md, "Traversal modes"). Both modes walk the
// same trees with the same rules; only the box, triangle and instance arithmetic differs.
enum class TraversalMode : uint8_t {
    // Double precision throughout (this header's and nv_trace.h's description): the
    // answer for the exact float inputs, as far as double can give it.
    kDouble,
    // A float32 hardware pipeline: the ray enters an instance through the float
    // world-to-object matrix in float, the watertight triangle test runs in float (double
    // only where an edge function is exactly 0), box tests in float widened by a few ulps.
    // Drivers (NVIDIA's, lavapipe's) trace in float32; their answers are this mode's.
    kFloat32,
};
const char* traversal_mode_name(TraversalMode mode);  // "double" / "float32"

struct Ray {
    float origin[3];
    float tmin;
    float direction[3];
    float tmax;
};

// SPIR-V RayFlags values.
enum RayFlag : uint32_t {
    kRayFlagNone = 0,
    kRayFlagOpaque = 0x1,
    kRayFlagNoOpaque = 0x2,
    kRayFlagTerminateOnFirstHit = 0x4,
    kRayFlagSkipClosestHitShader = 0x8,
    kRayFlagCullBackFacingTriangles = 0x10,
    kRayFlagCullFrontFacingTriangles = 0x20,
    kRayFlagCullOpaque = 0x40,
    kRayFlagCullNoOpaque = 0x80,
};

struct Hit {
    bool hit = false;
    float t = 0.0f;
    float u = 0.0f;               // barycentric weight of v1 (Vulkan's HitAttribute.x)
    float v = 0.0f;               // barycentric weight of v2
    float uv_error = 0.0f;        // how far a float32 evaluation's u, v may sit from these
    uint32_t triangle_index = 0;  // the triangle's index in the app's input (primitive index)
    uint32_t cluster_id = 0;
    uint32_t geometry_index = 0;
    bool front_face = false;
    bool opaque = false;
};

// A CLAS whose header and sections were checked once (read_object_header: every
// section, local index and BVH link lies inside the object), so tracing it is safe
// however its bytes were produced.
struct ClasView {
    std::span<const std::byte> bytes;
    ObjectHeader header;
};
// The view, or nullopt with `error` set when the bytes are no CLAS.
std::optional<ClasView> open_clas(std::span<const std::byte> bytes, std::string* error = nullptr);

// Closest hit in [tmin, tmax]; with kRayFlagTerminateOnFirstHit the first accepted hit.
Hit trace_closest(const ClasView& clas, const Ray& ray, uint32_t ray_flags,
                  TraversalMode mode = TraversalMode::kDouble);
// The reference for trace_closest: every stored triangle tested with the same triangle test
// and rules, no box. Ties (the same t) go to the triangle stored first; the BVH walk breaks
// them the same way, so both give the same hit.
Hit trace_closest_exhaustive(const ClasView& clas, const Ray& ray, uint32_t ray_flags,
                             TraversalMode mode = TraversalMode::kDouble);
// Whether any accepted hit exists in [tmin, tmax].
bool trace_any(const ClasView& clas, const Ray& ray, uint32_t ray_flags,
               TraversalMode mode = TraversalMode::kDouble);

// Convenience forms that check the object on every call (bytes that are no CLAS never hit).
Hit trace_closest(std::span<const std::byte> clas, const Ray& ray, uint32_t ray_flags,
                  TraversalMode mode = TraversalMode::kDouble);
bool trace_any(std::span<const std::byte> clas, const Ray& ray, uint32_t ray_flags,
               TraversalMode mode = TraversalMode::kDouble);

}  // namespace clastrace::engine
