#version 460
#extension GL_EXT_ray_query : require
#extension GL_GOOGLE_include_directive : require
#include "ray_check_common.glsl"

// The ray check against a KHR top level, as a ray query: the same answers the NV pipeline's
// shaders give (ray_check.rgen/rchit/rint): non-opaque triangle candidates are confirmed (no
// any-hit shader), AABB candidates get the slab test in object space against the box the
// layer uploaded, t = max(entry, t_min) generated when t <= exit and not past the closest
// committed hit; hit kind 0xFE/0xFF for triangles, 0 for boxes with (u, v) = (0, 0).
layout(local_size_x = 64) in;
layout(set = 0, binding = 0) uniform accelerationStructureEXT topLevel;
layout(std430, set = 0, binding = 1) readonly buffer Rays { TracedRay rays[]; };
layout(std430, set = 0, binding = 2) writeonly buffer Hits { RayHit hits[]; };
layout(push_constant) uniform Count { uint rayCount; };

// The slab test of the AABB candidate; returns the t to generate, or -1 for no hit.
float boxHit(rayQueryEXT q, float committedT) {
  const uint instance = rayQueryGetIntersectionInstanceIdEXT(q, false);
  const uint geometry = rayQueryGetIntersectionGeometryIndexEXT(q, false);
  const uint base = geometryAabbBase[instanceInfo[instance].y + geometry];
  if (base == 0xFFFFFFFFu) return -1.0;
  const uint b = (base + uint(rayQueryGetIntersectionPrimitiveIndexEXT(q, false))) * 6u;
  const vec3 lo = vec3(boxes[b], boxes[b + 1u], boxes[b + 2u]);
  const vec3 hi = vec3(boxes[b + 3u], boxes[b + 4u], boxes[b + 5u]);
  const vec3 o = rayQueryGetIntersectionObjectRayOriginEXT(q, false);
  const vec3 inv = vec3(1.0) / rayQueryGetIntersectionObjectRayDirectionEXT(q, false);
  const vec3 t0 = (lo - o) * inv;
  const vec3 t1 = (hi - o) * inv;
  const vec3 tNear = min(t0, t1);
  const vec3 tFar = max(t0, t1);
  const float entry = max(max(tNear.x, tNear.y), tNear.z);
  const float exit = min(min(tFar.x, tFar.y), tFar.z);
  const float t = max(entry, rayQueryGetRayTMinEXT(q));
  return (t <= exit && t <= committedT) ? t : -1.0;
}

void main() {
  const uint i = gl_GlobalInvocationID.x;
  if (i >= rayCount) return;
  const TracedRay r = rays[i];
  rayQueryEXT q;
  rayQueryInitializeEXT(q, topLevel, r.flagsMask.x, r.flagsMask.y & 0xFFu, r.originTmin.xyz,
                        r.originTmin.w, r.dirTmax.xyz, r.dirTmax.w);
  while (rayQueryProceedEXT(q)) {
    if (rayQueryGetIntersectionTypeEXT(q, false) ==
        gl_RayQueryCandidateIntersectionTriangleEXT) {
      rayQueryConfirmIntersectionEXT(q);
    } else {
      const bool committed = rayQueryGetIntersectionTypeEXT(q, true) !=
                             gl_RayQueryCommittedIntersectionNoneEXT;
      const float t = boxHit(q, committed ? rayQueryGetIntersectionTEXT(q, true) : r.dirTmax.w);
      if (t >= 0.0) rayQueryGenerateIntersectionEXT(q, t);
    }
  }
  RayHit h;
  h.hit = 0u;
  h.t = 0.0;
  h.customIndex = 0u;
  h.instanceId = 0u;
  h.primitiveId = 0u;
  h.geometryIndex = 0u;
  h.hitKind = 0u;
  h.u = 0.0;
  h.v = 0.0;
  h.pad0 = 0u;
  h.pad1 = 0u;
  h.pad2 = 0u;
  const uint kind = rayQueryGetIntersectionTypeEXT(q, true);
  if (kind != gl_RayQueryCommittedIntersectionNoneEXT) {
    h.hit = 1u;
    h.t = rayQueryGetIntersectionTEXT(q, true);
    h.customIndex = uint(rayQueryGetIntersectionInstanceCustomIndexEXT(q, true));
    h.instanceId = uint(rayQueryGetIntersectionInstanceIdEXT(q, true));
    h.primitiveId = uint(rayQueryGetIntersectionPrimitiveIndexEXT(q, true));
    h.geometryIndex = uint(rayQueryGetIntersectionGeometryIndexEXT(q, true));
    if (kind == gl_RayQueryCommittedIntersectionTriangleEXT) {
      h.hitKind = rayQueryGetIntersectionFrontFaceEXT(q, true) ? 0xFEu : 0xFFu;
      const vec2 uv = rayQueryGetIntersectionBarycentricsEXT(q, true);
      h.u = uv.x;
      h.v = uv.y;
    }
  }
  hits[i] = h;
}
