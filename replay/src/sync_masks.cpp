// SPDX-License-Identifier: Apache-2.0
#include "clastrace/replay/sync_masks.h"

#include <array>
#include <cstdio>
#include <initializer_list>

namespace clastrace::replay {
namespace {

struct FlagName {
    uint64_t bit;
    const char* name;    // without the VK_..._2_ prefix and the _BIT suffix
    const char* suffix;  // "_BIT", "_BIT_KHR", ...
};

// Written from the registry's values for Vulkan 1.3.239 plus the NV/KHR stages we meet.
constexpr FlagName kStageNames[] = {
    {0x00000001ull, "TOP_OF_PIPE", "_BIT"},
    {0x00000002ull, "DRAW_INDIRECT", "_BIT"},
    {0x00000004ull, "VERTEX_INPUT", "_BIT"},
    {0x00000008ull, "VERTEX_SHADER", "_BIT"},
    {0x00000010ull, "TESSELLATION_CONTROL_SHADER", "_BIT"},
    {0x00000020ull, "TESSELLATION_EVALUATION_SHADER", "_BIT"},
    {0x00000040ull, "GEOMETRY_SHADER", "_BIT"},
    {0x00000080ull, "FRAGMENT_SHADER", "_BIT"},
    {0x00000100ull, "EARLY_FRAGMENT_TESTS", "_BIT"},
    {0x00000200ull, "LATE_FRAGMENT_TESTS", "_BIT"},
    {0x00000400ull, "COLOR_ATTACHMENT_OUTPUT", "_BIT"},
    {0x00000800ull, "COMPUTE_SHADER", "_BIT"},
    {0x00001000ull, "ALL_TRANSFER", "_BIT"},
    {0x00002000ull, "BOTTOM_OF_PIPE", "_BIT"},
    {0x00004000ull, "HOST", "_BIT"},
    {0x00008000ull, "ALL_GRAPHICS", "_BIT"},
    {0x00010000ull, "ALL_COMMANDS", "_BIT"},
    {0x00020000ull, "COMMAND_PREPROCESS", "_BIT_NV"},
    {0x00040000ull, "CONDITIONAL_RENDERING", "_BIT_EXT"},
    {0x00080000ull, "TASK_SHADER", "_BIT_EXT"},
    {0x00100000ull, "MESH_SHADER", "_BIT_EXT"},
    {0x00200000ull, "RAY_TRACING_SHADER", "_BIT_KHR"},
    {0x00400000ull, "FRAGMENT_SHADING_RATE_ATTACHMENT", "_BIT_KHR"},
    {0x00800000ull, "FRAGMENT_DENSITY_PROCESS", "_BIT_EXT"},
    {0x01000000ull, "TRANSFORM_FEEDBACK", "_BIT_EXT"},
    {0x02000000ull, "ACCELERATION_STRUCTURE_BUILD", "_BIT_KHR"},
    {0x04000000ull, "VIDEO_DECODE", "_BIT_KHR"},
    {0x08000000ull, "VIDEO_ENCODE", "_BIT_KHR"},
    {0x10000000ull, "ACCELERATION_STRUCTURE_COPY", "_BIT_KHR"},
    {0x20000000ull, "OPTICAL_FLOW", "_BIT_NV"},
    {0x40000000ull, "MICROMAP_BUILD", "_BIT_EXT"},
    {0x100000000ull, "COPY", "_BIT"},
    {0x200000000ull, "RESOLVE", "_BIT"},
    {0x400000000ull, "BLIT", "_BIT"},
    {0x800000000ull, "CLEAR", "_BIT"},
    {0x1000000000ull, "INDEX_INPUT", "_BIT"},
    {0x2000000000ull, "VERTEX_ATTRIBUTE_INPUT", "_BIT"},
    {0x4000000000ull, "PRE_RASTERIZATION_SHADERS", "_BIT"},
    {0x8000000000ull, "SUBPASS_SHADING", "_BIT_HUAWEI"},
    {0x10000000000ull, "INVOCATION_MASK", "_BIT_HUAWEI"},
    {0x20000000000ull, "CLUSTER_CULLING_SHADER", "_BIT_HUAWEI"},
};

constexpr FlagName kAccessNames[] = {
    {0x00000001ull, "INDIRECT_COMMAND_READ", "_BIT"},
    {0x00000002ull, "INDEX_READ", "_BIT"},
    {0x00000004ull, "VERTEX_ATTRIBUTE_READ", "_BIT"},
    {0x00000008ull, "UNIFORM_READ", "_BIT"},
    {0x00000010ull, "INPUT_ATTACHMENT_READ", "_BIT"},
    {0x00000020ull, "SHADER_READ", "_BIT"},
    {0x00000040ull, "SHADER_WRITE", "_BIT"},
    {0x00000080ull, "COLOR_ATTACHMENT_READ", "_BIT"},
    {0x00000100ull, "COLOR_ATTACHMENT_WRITE", "_BIT"},
    {0x00000200ull, "DEPTH_STENCIL_ATTACHMENT_READ", "_BIT"},
    {0x00000400ull, "DEPTH_STENCIL_ATTACHMENT_WRITE", "_BIT"},
    {0x00000800ull, "TRANSFER_READ", "_BIT"},
    {0x00001000ull, "TRANSFER_WRITE", "_BIT"},
    {0x00002000ull, "HOST_READ", "_BIT"},
    {0x00004000ull, "HOST_WRITE", "_BIT"},
    {0x00008000ull, "MEMORY_READ", "_BIT"},
    {0x00010000ull, "MEMORY_WRITE", "_BIT"},
    {0x00020000ull, "COMMAND_PREPROCESS_READ", "_BIT_NV"},
    {0x00040000ull, "COMMAND_PREPROCESS_WRITE", "_BIT_NV"},
    {0x00080000ull, "COLOR_ATTACHMENT_READ_NONCOHERENT", "_BIT_EXT"},
    {0x00100000ull, "CONDITIONAL_RENDERING_READ", "_BIT_EXT"},
    {0x00200000ull, "ACCELERATION_STRUCTURE_READ", "_BIT_KHR"},
    {0x00400000ull, "ACCELERATION_STRUCTURE_WRITE", "_BIT_KHR"},
    {0x00800000ull, "FRAGMENT_SHADING_RATE_ATTACHMENT_READ", "_BIT_KHR"},
    {0x01000000ull, "FRAGMENT_DENSITY_MAP_READ", "_BIT_EXT"},
    {0x02000000ull, "TRANSFORM_FEEDBACK_WRITE", "_BIT_EXT"},
    {0x04000000ull, "TRANSFORM_FEEDBACK_COUNTER_READ", "_BIT_EXT"},
    {0x08000000ull, "TRANSFORM_FEEDBACK_COUNTER_WRITE", "_BIT_EXT"},
    {0x100000000ull, "SHADER_SAMPLED_READ", "_BIT"},
    {0x200000000ull, "SHADER_STORAGE_READ", "_BIT"},
    {0x400000000ull, "SHADER_STORAGE_WRITE", "_BIT"},
    {0x800000000ull, "VIDEO_DECODE_READ", "_BIT_KHR"},
    {0x1000000000ull, "VIDEO_DECODE_WRITE", "_BIT_KHR"},
    {0x2000000000ull, "VIDEO_ENCODE_READ", "_BIT_KHR"},
    {0x4000000000ull, "VIDEO_ENCODE_WRITE", "_BIT_KHR"},
    {0x8000000000ull, "INVOCATION_MASK_READ", "_BIT_HUAWEI"},
    {0x10000000000ull, "SHADER_BINDING_TABLE_READ", "_BIT_KHR"},
    {0x20000000000ull, "DESCRIPTOR_BUFFER_READ", "_BIT_EXT"},
    {0x40000000000ull, "OPTICAL_FLOW_READ", "_BIT_NV"},
    {0x80000000000ull, "OPTICAL_FLOW_WRITE", "_BIT_NV"},
    {0x100000000000ull, "MICROMAP_READ", "_BIT_EXT"},
    {0x200000000000ull, "MICROMAP_WRITE", "_BIT_EXT"},
};

constexpr uint64_t kSTop = 0x1, kSDrawIndirect = 0x2, kSVertexInput = 0x4, kSVs = 0x8, kSTcs = 0x10,
                   kSTes = 0x20, kSGs = 0x40, kSFs = 0x80, kSEft = 0x100, kSLft = 0x200,
                   kSColor = 0x400, kSCompute = 0x800, kSAllTransfer = 0x1000, kSBottom = 0x2000,
                   kSHost = 0x4000, kSAllGraphics = 0x8000, kSAllCommands = 0x10000,
                   kSPreprocess = 0x20000, kSCond = 0x40000, kSTask = 0x80000, kSMesh = 0x100000,
                   kSRt = 0x200000, kSFsr = 0x400000, kSFdp = 0x800000, kSXfb = 0x1000000,
                   kSAsBuild = 0x2000000, kSVdec = 0x4000000, kSVenc = 0x8000000,
                   kSAsCopy = 0x10000000, kSOflow = 0x20000000, kSMicromap = 0x40000000,
                   kSCopy = 0x100000000, kSResolve = 0x200000000, kSBlit = 0x400000000,
                   kSClear = 0x800000000, kSIndexInput = 0x1000000000, kSAttrInput = 0x2000000000,
                   kSPreRaster = 0x4000000000, kSSubpass = 0x8000000000,
                   kSInvocation = 0x10000000000, kSClusterCull = 0x20000000000;

// Our constants must be the header's values, and v1 bits must equal their v2 twins.
static_assert(kSAsBuild == VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR);
static_assert(kSAsCopy == VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR);
static_assert(kSCopy == VK_PIPELINE_STAGE_2_COPY_BIT && kSClear == VK_PIPELINE_STAGE_2_CLEAR_BIT);
static_assert(kSIndexInput == VK_PIPELINE_STAGE_2_INDEX_INPUT_BIT);
static_assert(kSPreRaster == VK_PIPELINE_STAGE_2_PRE_RASTERIZATION_SHADERS_BIT);
static_assert(kSMicromap == VK_PIPELINE_STAGE_2_MICROMAP_BUILD_BIT_EXT);
static_assert(kSClusterCull == VK_PIPELINE_STAGE_2_CLUSTER_CULLING_SHADER_BIT_HUAWEI);
static_assert(uint64_t(VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR) == kSAsBuild);
static_assert(uint64_t(VK_PIPELINE_STAGE_TRANSFER_BIT) == kSAllTransfer);
static_assert(uint64_t(VK_PIPELINE_STAGE_ALL_COMMANDS_BIT) == kSAllCommands);
static_assert(uint64_t(VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR) ==
              VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR);
static_assert(uint64_t(VK_ACCESS_INDIRECT_COMMAND_READ_BIT) ==
              VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
static_assert(uint64_t(VK_ACCESS_MEMORY_WRITE_BIT) == VK_ACCESS_2_MEMORY_WRITE_BIT);

constexpr uint64_t kAggregateStages =
    kSTop | kSBottom | kSVertexInput | kSAllTransfer | kSAllGraphics | kSAllCommands | kSPreRaster;

constexpr uint64_t known_stage_bits() {
    uint64_t m = 0;
    for (const FlagName& f : kStageNames) m |= f.bit;
    return m;
}
constexpr uint64_t kDeviceStages = known_stage_bits() & ~kAggregateStages & ~kSHost;

constexpr uint64_t kGraphicsStages = kSDrawIndirect | kSIndexInput | kSAttrInput | kSVs | kSTcs |
                                     kSTes | kSGs | kSFs | kSEft | kSLft | kSColor | kSCond |
                                     kSTask | kSMesh | kSFsr | kSFdp | kSXfb | kSSubpass |
                                     kSInvocation | kSClusterCull;

// The spec's pipeline stage orders ("Pipeline Stages" ordering rules), TOP/BOTTOM left out.
const std::initializer_list<uint64_t> kOrders[] = {
    {kSCond, kSDrawIndirect, kSIndexInput, kSAttrInput, kSVs, kSTcs, kSTes, kSGs, kSXfb, kSFsr,
     kSEft, kSFs, kSLft, kSColor},
    {kSCond, kSDrawIndirect, kSTask, kSMesh, kSFsr, kSEft, kSFs, kSLft, kSColor},
    {kSCond, kSDrawIndirect, kSCompute},
    {kSDrawIndirect, kSRt},
    {kSFdp, kSEft},
    {kSSubpass, kSInvocation},
    {kSDrawIndirect, kSClusterCull, kSFs},
};

struct StageTables {
    std::array<uint64_t, 64> earlier{};
    std::array<uint64_t, 64> later{};
    StageTables() {
        for (const auto& order : kOrders) {
            std::size_t i = 0;
            for (uint64_t s : order) {
                std::size_t j = 0;
                for (uint64_t t : order) {
                    if (j < i) earlier[std::size_t(__builtin_ctzll(s))] |= t;
                    if (j > i) later[std::size_t(__builtin_ctzll(s))] |= t;
                    ++j;
                }
                ++i;
            }
        }
    }
};
const StageTables& tables() {
    static const StageTables kT;
    return kT;
}

constexpr uint64_t kAShaderRead = 0x20, kAShaderWrite = 0x40, kAMemoryRead = 0x8000,
                   kAMemoryWrite = 0x10000, kASampled = 0x100000000, kAStorageRead = 0x200000000,
                   kAStorageWrite = 0x400000000;
constexpr uint64_t kWriteAccesses = 0x40 | 0x100 | 0x400 | 0x1000 | 0x4000 | 0x10000 | 0x40000 |
                                    0x400000 | 0x2000000 | 0x8000000 | 0x400000000 | 0x1000000000 |
                                    0x4000000000 | 0x80000000000 | 0x200000000000;
constexpr uint64_t known_access_bits() {
    uint64_t m = 0;
    for (const FlagName& f : kAccessNames) m |= f.bit;
    return m;
}
static_assert(kAStorageWrite == VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
static_assert(kASampled == VK_ACCESS_2_SHADER_SAMPLED_READ_BIT);
static_assert((kWriteAccesses & VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR) &&
              (kWriteAccesses & VK_ACCESS_2_MICROMAP_WRITE_BIT_EXT) &&
              (kWriteAccesses & VK_ACCESS_2_TRANSFER_WRITE_BIT));
constexpr uint64_t kAggregateAccesses = kAShaderRead | kAShaderWrite | kAMemoryRead | kAMemoryWrite;
constexpr uint64_t kAtomicWrites = kWriteAccesses & ~kAggregateAccesses;
constexpr uint64_t kAtomicReads = known_access_bits() & ~kWriteAccesses & ~kAggregateAccesses;

std::string names(uint64_t mask, const FlagName* table, std::size_t count, const char* prefix,
                  bool full) {
    if (mask == 0) return full ? std::string(prefix) + "NONE" : std::string("NONE");
    std::string out;
    uint64_t covered = 0;
    for (std::size_t i = 0; i < count; ++i) {
        if (!(mask & table[i].bit)) continue;
        if (!out.empty()) out += '|';
        if (full) out += prefix;
        out += table[i].name;
        if (full) out += table[i].suffix;
        covered |= table[i].bit;
    }
    if (uint64_t rest = mask & ~covered) {
        char buf[32];
        std::snprintf(buf, sizeof buf, "0x%llx", static_cast<unsigned long long>(rest));
        if (!out.empty()) out += '|';
        out += buf;
    }
    return out;
}

// The acceleration-structure copy commands run at ACCELERATION_STRUCTURE_COPY, which the model
// records as their accesses' stage; their spec pages let those accesses be synchronized with
// ACCELERATION_STRUCTURE_BUILD instead (the stage they ran in before VK_KHR_ray_tracing_
// maintenance1 added the copy stage, which v1 stage masks cannot name). So a scope that names
// the build stage takes the copy stage in too; naming the copy stage does not take builds in.
constexpr uint64_t with_copy_stage(uint64_t atoms) {
    return atoms & kSAsBuild ? atoms | kSAsCopy : atoms;
}

// The atoms of `mask` and every stage `beside` (StageTables::earlier or ::later) puts on their
// side; `every_stage` (BOTTOM for a source, TOP for a destination) stands for all of them.
StageMask ordered_scope(StageMask mask, uint64_t every_stage,
                        std::array<uint64_t, 64> StageTables::*beside) {
    uint64_t atoms = with_copy_stage(atomic_stages(mask));
    if (mask & every_stage) atoms |= kDeviceStages;
    uint64_t out = atoms;
    const std::array<uint64_t, 64>& table = tables().*beside;
    for (uint64_t m = atoms; m; m &= m - 1) out |= table[std::size_t(__builtin_ctzll(m))];
    return out;
}

}  // namespace

StageMask all_device_stages() { return kDeviceStages; }

StageMask atomic_stages(StageMask mask) {
    uint64_t out = mask & ~kAggregateStages;
    if (mask & (kSAllCommands)) out |= kDeviceStages;
    if (mask & kSAllGraphics) out |= kGraphicsStages;
    if (mask & kSAllTransfer) out |= kSCopy | kSResolve | kSBlit | kSClear | kSAsCopy;
    if (mask & kSVertexInput) out |= kSIndexInput | kSAttrInput;
    if (mask & kSPreRaster) out |= kSVs | kSTcs | kSTes | kSGs | kSTask | kSMesh | kSClusterCull;
    return out;
}

StageMask source_scope(StageMask mask) {
    return ordered_scope(mask, kSBottom, &StageTables::earlier);
}

StageMask destination_scope(StageMask mask) {
    return ordered_scope(mask, kSTop, &StageTables::later);
}

AccessMask atomic_accesses(AccessMask mask) {
    uint64_t out = mask & ~kAggregateAccesses;
    if (mask & kAMemoryRead) out |= kAtomicReads;
    if (mask & kAMemoryWrite) out |= kAtomicWrites;
    if (mask & kAShaderRead) out |= kASampled | kAStorageRead;
    if (mask & kAShaderWrite) out |= kAStorageWrite;
    return out;
}

AccessMask all_read_accesses() { return kAtomicReads; }
AccessMask all_write_accesses() { return kAtomicWrites; }
bool has_write(AccessMask mask) { return (mask & kWriteAccesses) != 0; }

std::string stage_names(StageMask mask) {
    return names(mask, kStageNames, std::size(kStageNames), "VK_PIPELINE_STAGE_2_", false);
}
std::string access_names(AccessMask mask) {
    return names(mask, kAccessNames, std::size(kAccessNames), "VK_ACCESS_2_", false);
}
std::string stage_flag_names(StageMask mask) {
    return names(mask, kStageNames, std::size(kStageNames), "VK_PIPELINE_STAGE_2_", true);
}
std::string access_flag_names(AccessMask mask) {
    return names(mask, kAccessNames, std::size(kAccessNames), "VK_ACCESS_2_", true);
}

}  // namespace clastrace::replay
