// SPDX-License-Identifier: Apache-2.0
// Reading a vkCmdBuildAccelerationStructureNV's inputs out of memory: triangles (every
// vertex format and index type NV allows, strides, the 3x4 transform), AABBs and
// instance records, with their checks and access ranges.
#pragma once

#include "clastrace/common/uninitialized_allocator.h"
#include "clastrace/engine/nv_build.h"
#include "geometry/box.h"

#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace clastrace::engine::nv {

using geometry::Box;

uint32_t nv_vertex_size(VkFormat format);
uint32_t nv_component_size(VkFormat format);
bool decode_nv_vertex(VkFormat format, const std::byte* src, float xyz[3]);

// What a build command calls its fields and rules. The NV command (the defaults) and the KHR
// command (khr_build.cpp) share the gathering, tree build, update and write; only the names
// of what they report, and the vertex formats they accept, differ.
struct Dialect {
    std::string geometries = "pInfo->pGeometries";  // + "[g]"
    std::string instances = "instanceData";
    std::string src = "src";
    std::string dst = "dst";
    std::string scratch = "scratch";
    std::string vertex_count = "vertexCount";   // what bounds an index
    std::string formats_by = "NV ray tracing";  // "... is not one <formats_by> allows"
    std::string reference_source = "handle vkGetAccelerationStructureHandleNV gave";
    uint32_t (*vertex_size)(VkFormat) = nv_vertex_size;  // 0: format not accepted
    uint32_t (*component_size)(VkFormat) = nv_component_size;
    bool (*decode_vertex)(VkFormat, const std::byte*, float[3]) = decode_nv_vertex;
    const char* vertex_format = kVuidVertexFormat;
    const char* reference = kVuidNvReference;
    const char* reference_alignment = nullptr;  // arrayOfPointers: each pointer's alignment
    const char* blas_not_built = kRuleNvBlasNotBuilt;
    const char* nan_component = kRuleNvNanComponent;
    const char* index_out_of_range = kRuleNvIndexOutOfRange;
    const char* update_not_allowed = kVuidNvUpdateNotAllowed;
    const char* made_inactive = kVuidNvMadeInactive;
    const char* made_active = kVuidNvMadeActive;
    const char* update_topology = kRuleNvUpdateTopology;
    const char* src_not_built = kRuleNvSrcNotBuilt;
    const char* memory_fault = kRuleNvMemoryFault;
    const char* object_too_large = kRuleNvObjectTooLarge;
    const char* scratch_overlap = kRuleNvScratchOverlap;
    const char* dst_overlaps_scratch = kRuleNvScratchOverlap;
    const char* input_overlaps_dst = kRuleNvInputOverlapsDst;
    bool instance_pointers = false;  // instances are read through an array of addresses
};

struct Context {
    const NvBuildCommand& command;
    MemoryImage& memory;
    const NvBuildOptions& options;
    ExecutionRecord& record;
    std::map<std::string, uint32_t> per_rule;
    Dialect dialect{};
    int64_t op_index = -1;      // the accesses' and findings' op (KHR: the pInfos index)
    uint64_t scratch_used = 0;  // bytes of scratch this build claims

    void finding(const char* rule, std::string message, uint64_t address = 0);
    void access(uint64_t begin, uint64_t size, VkAccessFlags2 access, bool write,
                std::string field);
    void close();
};

using common::UninitializedAllocator;  // the gather overwrites its arrays whole

struct BottomInput {
    bool aabbs = false;
    std::vector<NvGeometryRecord> geometries;
    // Every input primitive, geometry then index order.
    std::vector<NvPrimitiveRecord, UninitializedAllocator<NvPrimitiveRecord>> primitives;
    std::vector<uint8_t, UninitializedAllocator<uint8_t>> active;
    // The tree's input, taken while the primitives are read: each active primitive's box, in
    // primitive order, and the index of its record in `primitives`.
    std::vector<Box, UninitializedAllocator<Box>> boxes;
    std::vector<uint32_t, UninitializedAllocator<uint32_t>> source;
    // The bounds of those boxes' centroids (the Morton codes' range), taken with them.
    Box centroids = Box::empty();
};
struct TopInput {
    std::vector<NvInstanceRecord> instances;  // input order
};

// Throws MemoryFault when an input lies outside memory (the caller reports it). The arrays
// are the thread's last recycled ones where it kept some.
BottomInput gather_bottom(Context& c);
// Keeps the input's arrays for the thread's next gather_bottom (pages already faulted in).
void recycle_bottom_input(BottomInput&& in);
TopInput gather_top(Context& c);

// After the command's checks passed: reads src (update), gathers the inputs, builds or
// refits, checks overlaps and writes dst; fills record.ops[op_index or 0].
void run_build(Context& c);
// nv_vertex_size: 0 when VUID-VkGeometryTrianglesNV-vertexFormat-02430 does not allow it;
// decode_nv_vertex: false for such a format.

}  // namespace clastrace::engine::nv
