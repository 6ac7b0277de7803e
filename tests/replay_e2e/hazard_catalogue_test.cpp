// SPDX-License-Identifier: Apache-2.0
// The hazard catalogue: for every hazard class of the issue, one trace whose two commands
// lack the dependency the spec demands, and a twin that adds exactly the barrier (or
// semaphore, or disjoint range) the report suggests. The report must name the class, both
// commands, the fields and byte ranges, and a fix whose masks cover the twin's barrier.
#include <cstring>
#include "catalogue_replay.h"

#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>

#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <string>
#include <unistd.h>

namespace {

using namespace clastrace;
using namespace clastrace::test;
using namespace clastrace::test::catalogue;
using replay::FixKind;
using replay::HazardClass;

constexpr uint64_t kBuild = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
constexpr uint64_t kAsRead = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR;
constexpr uint64_t kAsWrite = VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
constexpr uint64_t kIndirect = VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT;
constexpr uint64_t kShaderRead = VK_ACCESS_2_SHADER_READ_BIT;
constexpr uint64_t kCopy = VK_PIPELINE_STAGE_2_COPY_BIT;
constexpr uint64_t kClear = VK_PIPELINE_STAGE_2_CLEAR_BIT;
constexpr uint64_t kCompute = VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT;
constexpr uint64_t kTransferWrite = VK_ACCESS_2_TRANSFER_WRITE_BIT;
constexpr uint64_t kTransferRead = VK_ACCESS_2_TRANSFER_READ_BIT;
constexpr uint64_t kStorageWrite = VK_ACCESS_2_SHADER_STORAGE_WRITE_BIT;

// One trace per case and twin (CLASTRACE_KEEP_TRACES=1 keeps them).
std::string temp_path(const std::string& name) { return temp_trace_path("hazard_catalogue", name); }

// The command indices the scene gave the two accesses (set while writing).
struct Commands {
    uint32_t prior = 0;
    uint32_t later = 0;
    uint32_t later_submission = 0;
};

using Scene = std::function<void(TraceScript& t, bool fixed, Commands& at)>;

struct HazardCase {
    const char* name;
    HazardClass hazard;
    Scene scene;
    const char* prior_command;  // Vulkan command name of the earlier access
    const char* prior_field;    // substrings of the fields the report names
    const char* later_field;
    uint64_t overlap_begin;  // the overlap lies in [overlap_begin, overlap_end)
    uint64_t overlap_end;
    FixKind fix;
    uint64_t fix_dst_stage;   // must be in the suggested fix
    uint64_t fix_dst_access;  // 0: an execution dependency suffices (write-after-read)
};

// Second command of a pair: its own scratch, outputs and destinations, so the only shared
// bytes are the ones the case is about.
ClusterCommand disjoint(ClusterCommand c) {
    c.info.scratchData = kScratch2;
    if (c.info.dstImplicitData) c.info.dstImplicitData = kDst2;
    c.info.dstAddressesArray.deviceAddress = kOut + 0x400;
    if (c.info.dstSizesArray.deviceAddress) c.info.dstSizesArray.deviceAddress = kSizes + 0x400;
    return c;
}

void build_barrier(TraceScript& t, uint64_t dst_access) {
    t.barrier(kBuild, kAsWrite, kBuild, dst_access);
}

std::vector<uint8_t> triangle_infos() {
    std::vector<TriangleInfo> infos{triangle_info(0), triangle_info(1)};
    return bytes_of(infos);
}

// `writer` builds objects at kDst that `reader`'s build then reads; the twin puts a build
// barrier between them.
HazardCase build_output_read_by_build(const char* name, ClusterCommand (*writer)(),
                                      ClusterCommand (*reader)(), const char* prior_field,
                                      const char* later_field, uint64_t overlap_end) {
    return {name,
            HazardClass::kReadAfterWrite,
            [writer, reader](TraceScript& t, bool fixed, Commands& at) {
                at.prior = writer().emit(t);
                if (fixed) build_barrier(t, kAsRead);
                at.later = disjoint(reader()).emit(t);
            },
            "vkCmdBuildClusterAccelerationStructureIndirectNV",
            prior_field,
            later_field,
            kDst,
            overlap_end,
            FixKind::kPipelineBarrier,
            kBuild,
            kAsRead};
}

// A transfer or dispatch (`write`, in `src_stage` with `src_access`) writes bytes the next
// triangle-cluster build reads with `read_access`; the twin puts that barrier between them.
struct InputWrite {
    void (*write)(TraceScript& t);
    uint64_t src_stage, src_access;
    const char* command;
    const char* field;
};
HazardCase input_written_before_build(const char* name, InputWrite w, uint64_t read_access,
                                      const char* later_field, uint64_t overlap_begin,
                                      uint64_t overlap_end) {
    return {name,
            HazardClass::kReadAfterWrite,
            [w, read_access](TraceScript& t, bool fixed, Commands& at) {
                at.prior = t.next_command();
                w.write(t);
                if (fixed) t.barrier(w.src_stage, w.src_access, kBuild, read_access);
                at.later = triangle_clusters(Destinations::kImplicit).emit(t);
            },
            w.command,
            w.field,
            later_field,
            overlap_begin,
            overlap_end,
            FixKind::kPipelineBarrier,
            kBuild,
            read_access};
}

ClusterCommand explicit_clusters() { return triangle_clusters(Destinations::kExplicit); }
ClusterCommand explicit_templates() { return triangle_templates(Destinations::kExplicit); }

const HazardCase kCases[] = {
    {"ScratchReusedByNextBuild", HazardClass::kWriteAfterWrite,
     [](TraceScript& t, bool fixed, Commands& at) {
         at.prior = triangle_clusters(Destinations::kImplicit).emit(t);
         if (fixed) build_barrier(t, kAsRead | kAsWrite);
         ClusterCommand second = disjoint(triangle_clusters(Destinations::kImplicit));
         second.info.scratchData = kScratch;
         at.later = second.emit(t);
     },
     "vkCmdBuildClusterAccelerationStructureIndirectNV", "scratchData", "scratchData", kScratch,
     kScratch + 32, FixKind::kPipelineBarrier, kBuild, kAsWrite},
    {"ScratchReusedAcrossQueuesWithoutSemaphore", HazardClass::kWriteAfterWrite,
     [](TraceScript& t, bool fixed, Commands& at) {
         at.prior = triangle_clusters(Destinations::kImplicit).emit(t);
         t.submit(0x9001, {},
                  fixed ? std::vector<SemaphoreUse>{{0x5e1, 0, kBuild}}
                        : std::vector<SemaphoreUse>{});
         ClusterCommand second = disjoint(triangle_clusters(Destinations::kImplicit));
         second.info.scratchData = kScratch;
         at.later = second.emit(t);
         at.later_submission = 1;
         t.submit(0x9002, fixed ? std::vector<SemaphoreUse>{{0x5e1, 0, kBuild}}
                                : std::vector<SemaphoreUse>{});
     },
     "vkCmdBuildClusterAccelerationStructureIndirectNV", "scratchData", "scratchData", kScratch,
     kScratch + 32, FixKind::kSemaphore, kBuild, kAsWrite},
    build_output_read_by_build(
        "ClusterReadByBottomLevelBeforeVisible", explicit_clusters, [] { return bottom_level(); },
        "*dstAddressesArray[", "clusterReferences[*]", kDst + 2 * kExplicitStride),
    build_output_read_by_build(
        "TemplateReadByInstantiateBeforeVisible", explicit_templates, [] { return instantiate(); },
        "*dstAddressesArray[0]", "clusterTemplateAddress", kDst + kExplicitStride),
    build_output_read_by_build(
        "TemplateReadByTemplateIndicesBeforeVisible", explicit_templates,
        [] { return template_indices(); }, "*dstAddressesArray[", "clusterTemplateAddress",
        kDst + 2 * kExplicitStride),
    build_output_read_by_build(
        "ClusterReadByMoveBeforeVisible", explicit_clusters, [] { return move_clusters(); },
        "*dstAddressesArray[", "srcAccelerationStructure", kDst + 2 * kExplicitStride),
    {"BottomLevelReadByMoveBeforeVisible", HazardClass::kReadAfterWrite,
     [](TraceScript& t, bool fixed, Commands& at) {
         triangle_clusters(Destinations::kExplicit).emit(t);
         build_barrier(t, kAsRead | kAsWrite);
         at.prior = disjoint(bottom_level()).emit(t);  // the BLAS lands at kDst2
         if (fixed) build_barrier(t, kAsRead);
         ClusterCommand move = move_clusters(1);
         move.move.type = VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_CLUSTERS_BOTTOM_LEVEL_NV;
         move.infos = bytes_of(std::vector<uint64_t>{kDst2});
         move.info.dstImplicitData = kDst2 + 0x10000;
         at.later = move.emit(t);
     },
     "vkCmdBuildClusterAccelerationStructureIndirectNV", "dstImplicitData[op 0]",
     "srcAccelerationStructure", kDst2, kDst2 + 0x10000, FixKind::kPipelineBarrier, kBuild,
     kAsRead},
    input_written_before_build(
        "InfosWrittenByCopy",
        {[](TraceScript& t) {
             const std::vector<uint8_t> infos = triangle_infos();
             t.copy(kStagingBuffer, 0, kInfosBuffer, 0, infos.size(), {{kStaging, infos}});
         },
         kCopy, kTransferWrite, "vkCmdCopyBuffer", "pRegions[0].dstOffset"},
        kIndirect, "srcInfosArray[*]", kInfos, kInfos + 2 * sizeof(TriangleInfo)),
    {"InfosWrittenByCopyBarrierWithoutIndirectRead", HazardClass::kReadAfterWrite,
     [](TraceScript& t, bool fixed, Commands& at) {
         const std::vector<uint8_t> infos = triangle_infos();
         at.prior = t.next_command();
         t.copy(kStagingBuffer, 0, kInfosBuffer, 0, infos.size(), {{kStaging, infos}});
         // The build reads its infos as INDIRECT_COMMAND_READ: ACCELERATION_STRUCTURE_READ does not do.
         t.barrier(kCopy, kTransferWrite, kBuild, fixed ? kIndirect : kAsRead);
         at.later = triangle_clusters(Destinations::kImplicit).emit(t);
     },
     "vkCmdCopyBuffer", "pRegions[0].dstOffset", "srcInfosArray[*]", kInfos,
     kInfos + 2 * sizeof(TriangleInfo), FixKind::kPipelineBarrier, kBuild, kIndirect},
    input_written_before_build("InfosWrittenByFill",
                               {[](TraceScript& t) { t.fill(kInfosBuffer, 0, 0x1000, 0); }, kClear,
                                kTransferWrite, "vkCmdFillBuffer", "dstOffset"},
                               kIndirect, "srcInfosArray[*]", kInfos,
                               kInfos + 2 * sizeof(TriangleInfo)),
    {"CountWrittenByUpdate", HazardClass::kReadAfterWrite,
     [](TraceScript& t, bool fixed, Commands& at) {
         at.prior = t.next_command();
         t.update(kInfosBuffer, kCount - kInfos, bytes_of(std::vector<uint32_t>{2}));
         if (fixed)
             t.buffer_barrier(kInfosBuffer, kCount - kInfos, 4, kClear, kTransferWrite, kBuild,
                              kIndirect);
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         c.info.srcInfosCount = kCount;
         at.later = c.emit(t);
     },
     "vkCmdUpdateBuffer", "pData", "srcInfosCount", kCount, kCount + 4, FixKind::kPipelineBarrier,
     kBuild, kIndirect},
    {"CountWrittenByCopy", HazardClass::kReadAfterWrite,
     [](TraceScript& t, bool fixed, Commands& at) {
         at.prior = t.next_command();
         t.copy(kStagingBuffer, 0, kInfosBuffer, kCount - kInfos, 4,
                {{kStaging, bytes_of(std::vector<uint32_t>{2})}});
         if (fixed) t.barrier(kCopy, kTransferWrite, kBuild, kIndirect);
         ClusterCommand c = triangle_clusters(Destinations::kImplicit);
         c.info.srcInfosCount = kCount;
         at.later = c.emit(t);
     },
     "vkCmdCopyBuffer", "pRegions[0].dstOffset", "srcInfosCount", kCount, kCount + 4,
     FixKind::kPipelineBarrier, kBuild, kIndirect},
    input_written_before_build(
        "InfosWrittenByDispatch",
        {[](TraceScript& t) {
             t.dispatch(kInfosBuffer, 0, 0x1000, {{kInfos, triangle_infos()}});
         },
         kCompute, kStorageWrite, "vkCmdDispatch", "set 0 binding 0[0]"},
        kIndirect, "srcInfosArray[*]", kInfos, kInfos + 2 * sizeof(TriangleInfo)),
    input_written_before_build("VerticesWrittenByCopy",
                               {[](TraceScript& t) {
                                    t.copy(kStagingBuffer, 0, kGeometryBuffer, 0, 0x300,
                                           {{kStaging, std::vector<uint8_t>(0x300, 0)}});
                                },
                                kCopy, kTransferWrite, "vkCmdCopyBuffer", "pRegions[0].dstOffset"},
                               kShaderRead, "vertexBuffer", kVertices, kVertices + 0x300),
    input_written_before_build("VerticesWrittenByUpdate",
                               {[](TraceScript& t) {
                                    t.update(kGeometryBuffer, 0, std::vector<uint8_t>(96, 0));
                                },
                                kClear, kTransferWrite, "vkCmdUpdateBuffer", "pData"},
                               kShaderRead, "vertexBuffer", kVertices, kVertices + 96),
    input_written_before_build("IndicesWrittenByDispatch",
                               {[](TraceScript& t) {
                                    t.dispatch(kGeometryBuffer, kIndices - kGeometry, 0x100);
                                },
                                kCompute, kStorageWrite, "vkCmdDispatch", "set 0 binding 0[0]"},
                               kShaderRead, "indexBuffer", kIndices, kIndices + 6),
    {"SizesReadByCopyBeforeVisible", HazardClass::kReadAfterWrite,
     [](TraceScript& t, bool fixed, Commands& at) {
         at.prior = triangle_clusters(Destinations::kImplicit).emit(t);
         if (fixed) t.barrier(kBuild, kAsWrite, kCopy, kTransferRead);
         at.later = t.next_command();
         t.copy(kOutBuffer, kSizes - kOut, kDst2Buffer, 0, 8);
     },
     "vkCmdBuildClusterAccelerationStructureIndirectNV", "dstSizesArray[", "pRegions[0].srcOffset",
     kSizes, kSizes + 8, FixKind::kPipelineBarrier, kCopy, kTransferRead},
    {"AddressesOverwrittenByFill", HazardClass::kWriteAfterWrite,
     [](TraceScript& t, bool fixed, Commands& at) {
         at.prior = triangle_clusters(Destinations::kImplicit).emit(t);
         if (fixed) t.barrier(kBuild, kAsWrite, kClear, kTransferWrite);
         at.later = t.next_command();
         t.fill(kOutBuffer, 0, 16, 0);
     },
     "vkCmdBuildClusterAccelerationStructureIndirectNV", "dstAddressesArray[", "dstOffset", kOut,
     kOut + 16, FixKind::kPipelineBarrier, kClear, kTransferWrite},
    {"ObjectsOverwrittenByNextBuild", HazardClass::kWriteAfterWrite,
     [](TraceScript& t, bool fixed, Commands& at) {
         at.prior = triangle_clusters(Destinations::kImplicit).emit(t);
         if (fixed) build_barrier(t, kAsWrite);
         ClusterCommand second = disjoint(triangle_clusters(Destinations::kImplicit));
         second.info.dstImplicitData = kDst;
         at.later = second.emit(t);
     },
     "vkCmdBuildClusterAccelerationStructureIndirectNV", "dstImplicitData", "dstImplicitData", kDst,
     kDst + 0x10000, FixKind::kPipelineBarrier, kBuild, kAsWrite},
    {"InfosOverwrittenWhileBuildReadsThem", HazardClass::kWriteAfterRead,
     [](TraceScript& t, bool fixed, Commands& at) {
         at.prior = triangle_clusters(Destinations::kImplicit).emit(t);
         if (fixed) t.barrier(kBuild, 0, kClear, 0);  // an execution dependency is enough
         at.later = t.next_command();
         t.fill(kInfosBuffer, 0, 64, 0);
     },
     "vkCmdBuildClusterAccelerationStructureIndirectNV", "srcInfosArray[0]", "dstOffset", kInfos,
     kInfos + 64, FixKind::kPipelineBarrier, kClear, 0},
    {"DeserializeOverObjectsStillBeingBuilt", HazardClass::kDeserializeInUse,
     [](TraceScript& t, bool fixed, Commands& at) {
         t.acceleration_structure(0xa5001, kDstBuffer, 0, 0x1000);  // over the CLAS at kDst
         at.prior = triangle_clusters(Destinations::kExplicit).emit(t);
         if (fixed)
             t.barrier(kBuild, kAsWrite, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR,
                       kAsWrite);
         at.later = t.next_command();
         // Another driver's blob (opaque, but a header that holds together: 0x100 bytes
         // serialized, 0x800 deserialized, no handles).
         std::vector<uint8_t> blob(0x100, 0x5a);
         const uint64_t header[3] = {0x100, 0x800, 0};
         std::memcpy(blob.data() + 32, header, sizeof header);
         t.deserialize(kStaging, 0xa5001, blob);
     },
     "vkCmdBuildClusterAccelerationStructureIndirectNV", "*dstAddressesArray[0]", "pInfo->dst",
     kDst, kDst + 0x1000, FixKind::kPipelineBarrier,
     VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_COPY_BIT_KHR, kAsWrite},
    {"CopySourceOverlapsDestination", HazardClass::kMoveOverlap,
     [](TraceScript& t, bool fixed, Commands& at) {
         at.prior = at.later = t.next_command();
         t.copy(kInfosBuffer, 0, kInfosBuffer, fixed ? 256 : 64, 128);
     },
     "vkCmdCopyBuffer", "pRegions[0].srcOffset", "pRegions[0].dstOffset", kInfos + 64, kInfos + 128,
     FixKind::kDisjointRanges, 0, 0},
};

class HazardCatalogue : public ::testing::TestWithParam<HazardCase> {
protected:
    replay::ReplayReport run(bool fixed, Commands* at) {
        return replay_catalogue_scene(temp_path(std::string(GetParam().name) +
                                                (fixed ? "_fixed.clt" : "_broken.clt")),
                                      [&](TraceScript& t) { GetParam().scene(t, fixed, *at); });
    }
};

// A foreign blob (the deserialization case) is reported as opaque: information, not a fault.
replay::ReplayReport without_opaque_notes(replay::ReplayReport r) {
    std::erase_if(r.findings, [](const replay::ReplayFinding& f) {
        return f.rule == "CLASTRACE-replay-nv-opaque-object" ||
               f.rule == "CLASTRACE-serialized-blob-from-another-driver";
    });
    return r;
}

TEST_P(HazardCatalogue, MissingDependencyIsOneHazardNamingBothCommandsFieldsAndFix) {
    const HazardCase& c = GetParam();
    Commands at;
    const replay::ReplayReport r = without_opaque_notes(run(false, &at));
    const std::string text = replay::format_text(r);
    EXPECT_TRUE(r.findings.empty()) << text;
    ASSERT_EQ(r.hazards.size(), 1u) << text;
    const replay::HazardReport& h = r.hazards[0];
    EXPECT_EQ(h.hazard, c.hazard) << text;
    EXPECT_EQ(std::string(h.prior.command.name), c.prior_command) << text;
    EXPECT_EQ(h.prior.command.command, at.prior) << text;
    EXPECT_EQ(h.later.command.command, at.later) << text;
    EXPECT_EQ(h.later.command.submission, at.later_submission) << text;
    EXPECT_NE(h.prior.field.find(c.prior_field), std::string::npos) << h.prior.field;
    EXPECT_NE(h.later.field.find(c.later_field), std::string::npos) << h.later.field;
    EXPECT_FALSE(h.overlap.empty());
    EXPECT_GE(h.overlap.begin, c.overlap_begin) << text;
    EXPECT_LE(h.overlap.end, c.overlap_end) << text;
    EXPECT_TRUE(h.prior.range.overlaps(h.overlap) && h.later.range.overlaps(h.overlap)) << text;
    EXPECT_EQ(h.fix.kind, c.fix) << text;
    EXPECT_EQ(h.fix.dst_stages & c.fix_dst_stage, c.fix_dst_stage) << text;
    EXPECT_EQ(h.fix.dst_access & c.fix_dst_access, c.fix_dst_access) << text;
    const std::string line = h.format();
    EXPECT_NE(line.find(std::string("SYNC-HAZARD-") + replay::hazard_class_name(c.hazard)),
              std::string::npos)
        << line;
    EXPECT_NE(line.find(h.later.field), std::string::npos) << line;
    EXPECT_NE(line.find(h.prior.field), std::string::npos) << line;
}

TEST_P(HazardCatalogue, TwinWithTheFixIsClean) {
    Commands at;
    const replay::ReplayReport r = without_opaque_notes(run(true, &at));
    EXPECT_TRUE(r.clean()) << replay::format_text(r);
}

INSTANTIATE_TEST_SUITE_P(Replay, HazardCatalogue, ::testing::ValuesIn(kCases),
                         [](const ::testing::TestParamInfo<HazardCase>& info) {
                             return std::string(info.param.name);
                         });

// A cluster move with noMoveOverlap whose destination overlaps its source: the engine's rule
// (the spec allows overlap only without noMoveOverlap).
TEST(HazardCatalogueMove, MoveOntoItsOwnSourceWithNoMoveOverlapIsReported) {
    for (bool broken : {true, false}) {
        uint32_t move_command = 0;
        const replay::ReplayReport r =
            replay_catalogue_scene(temp_path(broken ? "move_overlap.clt" : "move_disjoint.clt"),
                                   [&](TraceScript& t) {
                                       triangle_clusters(Destinations::kExplicit).emit(t);
                                       build_barrier(t, kAsRead | kAsWrite);
                                       ClusterCommand move = move_clusters(1);
                                       move.info.dstImplicitData =
                                           broken ? kDst + 128 : kDst2;  // the source is at kDst
                                       move.info.scratchData = kScratch2;
                                       move_command = move.emit(t);
                                   });
        if (!broken) {
            EXPECT_TRUE(r.clean()) << replay::format_text(r);
            continue;
        }
        ASSERT_FALSE(r.findings.empty()) << replay::format_text(r);
        EXPECT_EQ(r.findings[0].rule, "CLASTRACE-move-overlaps-with-noMoveOverlap");
        EXPECT_EQ(r.findings[0].where.command, move_command);
        EXPECT_EQ(r.findings[0].op_index, 0);  // the op that moves, not the command
    }
}

}  // namespace
