#include "clastrace/replay/sync_masks.hpp"

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

constexpr uint64_t S_TOP = 0x1, S_DRAW_INDIRECT = 0x2, S_VERTEX_INPUT = 0x4, S_VS = 0x8, S_TCS = 0x10,
                   S_TES = 0x20, S_GS = 0x40, S_FS = 0x80, S_EFT = 0x100, S_LFT = 0x200, S_COLOR = 0x400,
                   S_COMPUTE = 0x800, S_ALL_TRANSFER = 0x1000, S_BOTTOM = 0x2000, S_HOST = 0x4000,
                   S_ALL_GRAPHICS = 0x8000, S_ALL_COMMANDS = 0x10000, S_PREPROCESS = 0x20000,
                   S_COND = 0x40000, S_TASK = 0x80000, S_MESH = 0x100000, S_RT = 0x200000, S_FSR = 0x400000,
                   S_FDP = 0x800000, S_XFB = 0x1000000, S_AS_BUILD = 0x2000000, S_VDEC = 0x4000000,
                   S_VENC = 0x8000000, S_AS_COPY = 0x10000000, S_OFLOW = 0x20000000, S_MICROMAP = 0x40000000,
                   S_COPY = 0x100000000, S_RESOLVE = 0x200000000, S_BLIT = 0x400000000, S_CLEAR = 0x800000000,
                   S_INDEX_INPUT = 0x1000000000, S_ATTR_INPUT = 0x2000000000, S_PRE_RASTER = 0x4000000000,
                   S_SUBPASS = 0x8000000000, S_INVOCATION = 0x10000000000, S_CLUSTER_CULL = 0x20000000000;

// Our constants must be the header's values, and v1 bits must equal their v2 twins.
static_assert(S_AS_BUILD == VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR);
static_assert(S_AS_COPY == VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR);
static_assert(S_COPY == VK_PIPELINE_STAGE_2_COPY_BIT && S_CLEAR == VK_PIPELINE_STAGE_2_CLEAR_BIT);
static_assert(S_INDEX_INPUT == VK_PIPELINE_STAGE_2_INDEX_INPUT_BIT);
static_assert(S_PRE_RASTER == VK_PIPELINE_STAGE_2_PRE_RASTERIZATION_SHADERS_BIT);
static_assert(S_MICROMAP == VK_PIPELINE_STAGE_2_MICROMAP_BUILD_BIT_EXT);
static_assert(S_CLUSTER_CULL == VK_PIPELINE_STAGE_2_CLUSTER_CULLING_SHADER_BIT_HUAWEI);
static_assert(uint64_t(VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR) == S_AS_BUILD);
static_assert(uint64_t(VK_PIPELINE_STAGE_TRANSFER_BIT) == S_ALL_TRANSFER);
static_assert(uint64_t(VK_PIPELINE_STAGE_ALL_COMMANDS_BIT) == S_ALL_COMMANDS);
static_assert(uint64_t(VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR) == VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR);
static_assert(uint64_t(VK_ACCESS_INDIRECT_COMMAND_READ_BIT) == VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
static_assert(uint64_t(VK_ACCESS_MEMORY_WRITE_BIT) == VK_ACCESS_2_MEMORY_WRITE_BIT);

constexpr uint64_t kAggregateStages =
    S_TOP | S_BOTTOM | S_VERTEX_INPUT | S_ALL_TRANSFER | S_ALL_GRAPHICS | S_ALL_COMMANDS | S_PRE_RASTER;

constexpr uint64_t known_stage_bits() {
    uint64_t m = 0;
    for (const FlagName& f : kStageNames) m |= f.bit;
    return m;
}
constexpr uint64_t kDeviceStages = known_stage_bits() & ~kAggregateStages & ~S_HOST;

constexpr uint64_t kGraphicsStages = S_DRAW_INDIRECT | S_INDEX_INPUT | S_ATTR_INPUT | S_VS | S_TCS | S_TES | S_GS |
                                     S_FS | S_EFT | S_LFT | S_COLOR | S_COND | S_TASK | S_MESH | S_FSR | S_FDP |
                                     S_XFB | S_SUBPASS | S_INVOCATION | S_CLUSTER_CULL;

// The spec's pipeline stage orders ("Pipeline Stages" ordering rules), TOP/BOTTOM left out.
const std::initializer_list<uint64_t> kOrders[] = {
    {S_COND, S_DRAW_INDIRECT, S_INDEX_INPUT, S_ATTR_INPUT, S_VS, S_TCS, S_TES, S_GS, S_XFB, S_FSR, S_EFT, S_FS,
     S_LFT, S_COLOR},
    {S_COND, S_DRAW_INDIRECT, S_TASK, S_MESH, S_FSR, S_EFT, S_FS, S_LFT, S_COLOR},
    {S_COND, S_DRAW_INDIRECT, S_COMPUTE},
    {S_DRAW_INDIRECT, S_RT},
    {S_FDP, S_EFT},
    {S_SUBPASS, S_INVOCATION},
    {S_DRAW_INDIRECT, S_CLUSTER_CULL, S_FS},
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
    static const StageTables t;
    return t;
}

constexpr uint64_t A_SHADER_READ = 0x20, A_SHADER_WRITE = 0x40, A_MEMORY_READ = 0x8000, A_MEMORY_WRITE = 0x10000,
                   A_SAMPLED = 0x100000000, A_STORAGE_READ = 0x200000000, A_STORAGE_WRITE = 0x400000000;
constexpr uint64_t kWriteAccesses = 0x40 | 0x100 | 0x400 | 0x1000 | 0x4000 | 0x10000 | 0x40000 | 0x400000 |
                                    0x2000000 | 0x8000000 | 0x400000000 | 0x1000000000 | 0x4000000000 |
                                    0x80000000000 | 0x200000000000;
constexpr uint64_t known_access_bits() {
    uint64_t m = 0;
    for (const FlagName& f : kAccessNames) m |= f.bit;
    return m;
}
static_assert(A_STORAGE_WRITE == VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT);
static_assert(A_SAMPLED == VK_ACCESS_2_SHADER_SAMPLED_READ_BIT);
static_assert((kWriteAccesses & VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR) &&
              (kWriteAccesses & VK_ACCESS_2_MICROMAP_WRITE_BIT_EXT) && (kWriteAccesses & VK_ACCESS_2_TRANSFER_WRITE_BIT));
constexpr uint64_t kAggregateAccesses = A_SHADER_READ | A_SHADER_WRITE | A_MEMORY_READ | A_MEMORY_WRITE;
constexpr uint64_t kAtomicWrites = kWriteAccesses & ~kAggregateAccesses;
constexpr uint64_t kAtomicReads = known_access_bits() & ~kWriteAccesses & ~kAggregateAccesses;

std::string names(uint64_t mask, const FlagName* table, std::size_t count, const char* prefix, bool full) {
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

}  // namespace

StageMask all_device_stages() { return kDeviceStages; }

StageMask atomic_stages(StageMask mask) {
    uint64_t out = mask & ~kAggregateStages;
    if (mask & (S_ALL_COMMANDS)) out |= kDeviceStages;
    if (mask & S_ALL_GRAPHICS) out |= kGraphicsStages;
    if (mask & S_ALL_TRANSFER) out |= S_COPY | S_RESOLVE | S_BLIT | S_CLEAR | S_AS_COPY;
    if (mask & S_VERTEX_INPUT) out |= S_INDEX_INPUT | S_ATTR_INPUT;
    if (mask & S_PRE_RASTER) out |= S_VS | S_TCS | S_TES | S_GS | S_TASK | S_MESH | S_CLUSTER_CULL;
    return out;
}

StageMask source_scope(StageMask mask) {
    uint64_t atoms = atomic_stages(mask);
    if (mask & S_BOTTOM) atoms |= kDeviceStages;
    uint64_t out = atoms;
    const StageTables& t = tables();
    for (uint64_t m = atoms; m; m &= m - 1) out |= t.earlier[std::size_t(__builtin_ctzll(m))];
    return out;
}

StageMask destination_scope(StageMask mask) {
    uint64_t atoms = atomic_stages(mask);
    if (mask & S_TOP) atoms |= kDeviceStages;
    uint64_t out = atoms;
    const StageTables& t = tables();
    for (uint64_t m = atoms; m; m &= m - 1) out |= t.later[std::size_t(__builtin_ctzll(m))];
    return out;
}

AccessMask atomic_accesses(AccessMask mask) {
    uint64_t out = mask & ~kAggregateAccesses;
    if (mask & A_MEMORY_READ) out |= kAtomicReads;
    if (mask & A_MEMORY_WRITE) out |= kAtomicWrites;
    if (mask & A_SHADER_READ) out |= A_SAMPLED | A_STORAGE_READ;
    if (mask & A_SHADER_WRITE) out |= A_STORAGE_WRITE;
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
