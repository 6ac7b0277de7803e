// Shared by the ray-check shaders: the layout of one ray and one answer (48 bytes each, std430),
// exactly as clastrace::capture::NvTracedRay / NvRayHit lay them out on the host.
struct TracedRay {
  vec4 originTmin;   // xyz origin, w t_min
  vec4 dirTmax;      // xyz direction, w t_max
  uvec4 flagsMask;   // x ray flags, y cull mask
};
struct RayHit {
  uint hit;          // 0 miss, 1 hit
  float t;
  uint customIndex;
  uint instanceId;
  uint primitiveId;
  uint geometryIndex;
  uint hitKind;
  float u;
  float v;
  uint pad0, pad1, pad2;
};

// Per instance record of the top level: its SBT record offset and the first slot of its
// bottom level's geometries in geometryAabbBase.
layout(std430, set = 0, binding = 3) readonly buffer InstanceTable { uvec2 instanceInfo[]; };
// Per geometry slot: index of its first box in `boxes`, or 0xFFFFFFFF for triangles.
layout(std430, set = 0, binding = 4) readonly buffer GeometryTable { uint geometryAabbBase[]; };
// Every AABB of every AABB geometry: minX minY minZ maxX maxY maxZ.
layout(std430, set = 0, binding = 5) readonly buffer BoxTable { float boxes[]; };
