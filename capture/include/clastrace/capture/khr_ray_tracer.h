// SPDX-License-Identifier: Apache-2.0
// Traces a list of rays against a VkAccelerationStructureKHR top level with a small embedded
// ray-query compute pipeline (capture/shaders/ray_check.comp), and returns the driver's answers,
// with the same rays, answers and scene tables as the NV tracer (nv_ray_tracer.h), so one ray
// check and one replay comparison serve both: the compute shader gives the answers the NV
// pipeline's hit shaders give (kKhrRayCheckRule).
//
// The device needs VK_KHR_ray_query with the rayQuery feature enabled.
#pragma once

#include "clastrace/capture/nv_ray_tracer.h"

namespace clastrace::capture {

// Traces `rays` against `top_level` after every earlier command on `queue` (a full barrier
// leads the command buffer) and waits for the answers (up to 10 s). False + `error` on any
// failure; nothing is left allocated either way. `context.ray_tracing_properties` is unused.
bool trace_rays_khr(const NvRayTracerContext& context, VkAccelerationStructureKHR top_level,
                    const NvTraceScene& scene, const std::vector<NvTracedRay>& rays,
                    std::vector<NvRayHit>& hits, std::string& error);

// The rule the compute shader applies, written out for the label of a RayQueryCheck.
extern const char* const kKhrRayCheckRule;

}  // namespace clastrace::capture
