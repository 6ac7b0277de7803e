// SPDX-License-Identifier: Apache-2.0
// Test scenes for the KHR engine path: the NV tests' scene specs (nv_scene.h) written into
// a MemoryImage the way a KHR application lays them out (firstVertex, primitiveOffset,
// transformOffset, 16-bit or no indices, instances packed or through pointers) and built
// with engine::execute_khr_build; Embree sees the same scene from the same specs.
#pragma once

#include "../engine_nv/nv_scene.h"

#include <clastrace/engine/khr_build.h>

namespace clastrace::khrtest {

namespace eng = clastrace::engine;
namespace ts = clastrace::testsupport;
using nvtest::BlasSpec;
using nvtest::InstanceSpec;
using nvtest::NvWorld;

// How the inputs are laid out in memory (the answer must not depend on it).
struct Layout {
    uint32_t first_vertex = 0;      // junk vertices in front of the mesh's
    uint32_t primitive_offset = 0;  // junk bytes in front of the indices (or vertices)
    bool uint16_indices = false;
    bool no_indices = false;          // VK_INDEX_TYPE_NONE_KHR: vertices expanded per triangle
    bool identity_transform = false;  // transformData given, at transformOffset 16
    bool instance_pointers = false;   // arrayOfPointers
};

eng::KhrObject make_object(NvWorld& w, VkAccelerationStructureTypeKHR type, uint64_t size);
// The BLAS inputs written as `layout` says; the info's ranges included, dst and scratch not.
eng::KhrBuildInfo blas_info(NvWorld& w, const BlasSpec& spec, const Layout& layout,
                            VkBuildAccelerationStructureFlagsKHR flags = 0);
// A top-level info over `instance_data` (packed records, or pointers when `pointers`).
eng::KhrBuildInfo tlas_info(uint64_t instance_data, uint32_t count, bool pointers,
                            VkBuildAccelerationStructureFlagsKHR flags = 0);
// Gives the info a dst of exactly the engine's size and enough scratch; runs it alone.
eng::ExecutionRecord build(NvWorld& w, eng::KhrBuildInfo& info,
                           const eng::KhrBuildOptions& options = {});
// The instance records of `instances` (NV and KHR share VkAccelerationStructureInstanceKHR's
// layout) and, for pointers, the array of their addresses; returns the geometry's data.
uint64_t put_instances(NvWorld& w, const std::vector<InstanceSpec>& instances,
                       const std::vector<uint64_t>& blas_addresses, bool pointers);

struct KhrScene {
    NvWorld world;
    std::vector<eng::KhrObject> blas;
    eng::KhrObject tlas;
    std::vector<std::string> findings;  // "rule: message" of every build
};
std::unique_ptr<KhrScene> build_scene(const std::vector<BlasSpec>& blas,
                                      const std::vector<InstanceSpec>& instances,
                                      const Layout& layout,
                                      VkBuildAccelerationStructureFlagsKHR flags = 0);

bool has(const eng::ExecutionRecord& r, const std::string& rule);

}  // namespace clastrace::khrtest
