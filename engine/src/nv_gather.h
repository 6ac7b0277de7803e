// SPDX-License-Identifier: Apache-2.0
// Reading a vkCmdBuildAccelerationStructureNV's inputs out of memory: triangles (every
// vertex format and index type NV allows, strides, the 3x4 transform), AABBs and
// instance records, with their checks and access ranges.
#pragma once

#include "clastrace/engine/nv_build.h"

#include <map>
#include <string>
#include <vector>

namespace clastrace::engine::nv {

struct Context {
    const NvBuildCommand& command;
    MemoryImage& memory;
    const NvBuildOptions& options;
    ExecutionRecord& record;
    std::map<std::string, uint32_t> per_rule;

    void finding(const char* rule, std::string message, uint64_t address = 0);
    void access(uint64_t begin, uint64_t size, VkAccessFlags2 access, bool write,
                std::string field);
    void close();
};

struct BottomInput {
    bool aabbs = false;
    std::vector<NvGeometryRecord> geometries;
    std::vector<NvPrimitiveRecord> primitives;  // every input primitive, geometry then index order
    std::vector<uint8_t> active;
};
struct TopInput {
    std::vector<NvInstanceRecord> instances;  // input order
};

// Throws MemoryFault when an input lies outside memory (the caller reports it).
BottomInput gather_bottom(Context& c);
TopInput gather_top(Context& c);

// Decodes one vertex of the NV-allowed formats; false for any other format.
bool decode_nv_vertex(VkFormat format, const std::byte* src, float xyz[3]);
uint32_t nv_vertex_size(
    VkFormat format);  // 0: not allowed by VUID-VkGeometryTrianglesNV-vertexFormat-02430
uint32_t nv_component_size(VkFormat format);

}  // namespace clastrace::engine::nv
