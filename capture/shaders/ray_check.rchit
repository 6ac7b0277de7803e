#version 460
#extension GL_NV_ray_tracing : require
#extension GL_GOOGLE_include_directive : require
#include "ray_check_common.glsl"

layout(location = 0) rayPayloadInNV RayHit payload;
hitAttributeNV vec2 attributes;
// Each hit record carries its own index in the hit table after the group handle.
layout(shaderRecordNV, std430) buffer HitRecord { uint recordIndex; };

void main() {
  payload.hit = 1u;
  payload.t = gl_HitTNV;
  payload.customIndex = uint(gl_InstanceCustomIndexNV);
  payload.instanceId = uint(gl_InstanceID);
  payload.primitiveId = uint(gl_PrimitiveID);
  payload.geometryIndex = recordIndex - instanceInfo[gl_InstanceID].x;
  payload.hitKind = gl_HitKindNV;
  payload.u = attributes.x;
  payload.v = attributes.y;
}
