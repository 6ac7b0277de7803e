// SPDX-License-Identifier: Apache-2.0
// Bug programs that break a rule of one cluster command (its VUIDs and the engine's own rules):
// each finding at the command, the op and the address the program says the bug touches.
#include "bug_programs_support.h"

#include <algorithm>
#include <string>

namespace clastrace::bug_programs {
namespace {

TEST_F(BugPrograms, MoveOntoItsOwnSourceDespiteNoMoveOverlapIsFoundAtItsOp) {
    CAPTURE_AND_REPLAY(r, "move_after_build", "--overlap");
    EXPECT_TRUE(r.hazards().empty()) << r.describe();
    ASSERT_EQ(r.findings().size(), 1u) << r.describe();
    const json& f = r.findings().at(0);
    EXPECT_EQ(f.at("rule"), "CLASTRACE-move-overlaps-with-noMoveOverlap");
    EXPECT_EQ(f.at("op_index"), 2);
    EXPECT_EQ(f.at("where").at("name"), kClusterBuild);
    EXPECT_EQ(f.at("where").at("command"), 2);  // after the build and the barrier
    EXPECT_EQ(parse_address(f.at("address")), r.range("last_source").begin);
}

// Every finding is a memory fault in command `command` writing a field named `field`[...];
// the first at op `op` and `address`.
void expect_result_write_faults(const Replayed& r, uint32_t command, int op,
                                const std::string& field, uint64_t address) {
    EXPECT_TRUE(r.hazards().empty()) << r.describe();
    ASSERT_FALSE(r.findings().empty()) << r.describe();
    for (const json& f : r.findings()) {
        EXPECT_EQ(f.at("rule"), "CLASTRACE-memory-fault");
        EXPECT_EQ(f.at("where").at("command"), command);
        EXPECT_NE(f.at("message").get<std::string>().find("field " + field + "["),
                  std::string::npos)
            << f.at("message");
    }
    const json& first = r.findings().at(0);
    EXPECT_EQ(first.at("op_index"), op);
    EXPECT_NE(first.at("message").get<std::string>().find(
                  "field " + field + "[" + (field == "dstImplicitData" ? "op " : "") +
                  std::to_string(op) + "]"),
              std::string::npos)
        << first.at("message");
    EXPECT_EQ(parse_address(first.at("address")), address);
}

TEST_F(BugPrograms, BottomLevelImplicitDataInHalfTheQueriedSizeIsAMemoryFault) {
    CAPTURE_AND_REPLAY(r, "result_memory_too_small");
    // The span the queried size gives dstImplicitData runs past the half buffer into whatever
    // the driver placed next; when that is a scratch buffer, the span overlapping it is 12303,
    // the same bug seen from the scratch's side (it depends on the driver's allocator).
    Replayed faults = r;
    json& findings = faults.report.at("findings");
    findings.erase(
        std::remove_if(findings.begin(), findings.end(),
                       [](const json& f) {
                           return f.at("rule") ==
                                  "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-"
                                  "dstImplicitData-12303";
                       }),
        findings.end());
    EXPECT_EQ(faults.findings().size(), 1u) << r.describe();
    expect_result_write_faults(faults, 2, 0, "dstImplicitData", r.range("implicit_data").begin);
}

TEST_F(BugPrograms, SizesArrayInUint16BufferFaultsFromItsSecondEntry) {
    CAPTURE_AND_REPLAY(r, "result_memory_too_small", "--sizes-short");
    expect_result_write_faults(r, 0, 1, "dstSizesArray", r.range("sizes").begin + 4);
}

TEST_F(BugPrograms, ResultsInQueriedSizesAreClean) {
    CAPTURE_AND_REPLAY(r, "result_memory_too_small", "--fixed");
    expect_clean(r);
}

// The single finding of rule `rule` at op `op` (-1: the command) of the one build.
const json* only_finding(const Replayed& r, const std::string& rule, int op) {
    EXPECT_TRUE(r.hazards().empty()) << r.describe();
    const json* found = nullptr;
    for (const json& f : r.findings())
        if (f.at("rule") == rule) {
            EXPECT_EQ(found, nullptr) << "twice: " << rule;
            found = &f;
        }
    EXPECT_NE(found, nullptr) << rule << " not found in\n" << r.describe();
    if (!found) return nullptr;
    EXPECT_EQ(found->at("op_index"), op);
    EXPECT_EQ(found->at("where").at("name"), kClusterBuild);
    EXPECT_EQ(found->at("where").at("submission"), 0);
    EXPECT_EQ(found->at("where").at("command"), 0);  // the program's only command
    return found;
}

TEST_F(BugPrograms, IndexPastTheClusterVerticesIsFoundAtItsOp) {
    CAPTURE_AND_REPLAY(r, "memory_rules", "index-out-of-range");
    EXPECT_EQ(r.findings().size(), 1u) << r.describe();
    if (const json* f = only_finding(r, "CLASTRACE-index-out-of-range", 1)) {
        EXPECT_EQ(parse_address(f->at("address")), r.range("cluster1_indices").begin);
    }
}

TEST_F(BugPrograms, TriangleCountAboveTheInputLimitIsFoundAtItsOp) {
    CAPTURE_AND_REPLAY(r, "memory_rules", "too-many-triangles");
    only_finding(r, "CLASTRACE-count-above-triangle-cluster-input", 0);
}

TEST_F(BugPrograms, CountAboveMaxAccelerationStructureCountIsFound) {
    CAPTURE_AND_REPLAY(r, "memory_rules", "count-above-max");
    EXPECT_EQ(r.findings().size(), 1u) << r.describe();
    if (const json* f = only_finding(
            r, "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10453", -1)) {
        EXPECT_EQ(parse_address(f->at("address")), r.range("count").begin);
    }
}

TEST_F(BugPrograms, MisalignedExplicitDestinationIsFoundAtItsOp) {
    CAPTURE_AND_REPLAY(r, "memory_rules", "misaligned-dst");
    EXPECT_EQ(r.findings().size(), 1u) << r.describe();
    if (const json* f = only_finding(r, "CLASTRACE-destination-misaligned", 1)) {
        EXPECT_EQ(parse_address(f->at("address")), r.range("destination1").begin);
    }
}

TEST_F(BugPrograms, OverlappingExplicitDestinationsAreFound) {
    CAPTURE_AND_REPLAY(r, "memory_rules", "overlapping-dst");
    EXPECT_EQ(r.findings().size(), 1u) << r.describe();
    if (const json* f = only_finding(
            r, "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-dstAddressesArray-12302",
            -1)) {
        EXPECT_EQ(parse_address(f->at("address")), r.range("destination1").begin);
        EXPECT_NE(f->at("message").get<std::string>().find("op 1's object"), std::string::npos);
    }
}

TEST_F(BugPrograms, ExplicitDestinationSmallerThanItsObjectIsFoundAtItsOp) {
    CAPTURE_AND_REPLAY(r, "memory_rules", "dst-too-small");
    EXPECT_EQ(r.findings().size(), 1u) << r.describe();
    if (const json* f = only_finding(r, "CLASTRACE-explicit-destination-smaller-than-object", 1)) {
        EXPECT_EQ(parse_address(f->at("address")), r.range("destination1").begin);
    }
}

TEST_F(BugPrograms, ValidImplicitAndExplicitBuildsAreClean) {
    CAPTURE_AND_REPLAY(implicit, "memory_rules");
    expect_clean(implicit);
    CAPTURE_AND_REPLAY(explicit_run, "memory_rules", "aligned-dst");
    expect_clean(explicit_run);
}

TEST_F(BugPrograms, CountCopiedFromGpuAboveMaxAccelerationStructureCountIsFound) {
    CAPTURE_AND_REPLAY(r, "count_written_no_barrier", "--above-max");
    EXPECT_EQ(r.findings().size(), 1u) << r.describe();
    const json* f = nullptr;
    for (const json& each : r.findings()) f = &each;
    ASSERT_NE(f, nullptr);
    EXPECT_EQ(f->at("rule"),
              "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10453");
    EXPECT_EQ(f->at("where").at("command"), 2);  // after the copy and the barrier
    EXPECT_EQ(parse_address(f->at("address")), r.range("count").begin);
    EXPECT_TRUE(r.hazards().empty()) << r.describe();
}

TEST_F(BugPrograms, ScratchHalfTheQueriedSizeIsFound) {
    CAPTURE_AND_REPLAY(r, "scratch_too_small");
    // The queried span runs past the half buffer into whatever the driver placed next; when
    // that is a destination, 12302/12303 is the same bug seen from its side (allocator-made).
    const json* f =
        only_finding(r, "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-scratchData-12300",
                     -1);
    if (f) {
        EXPECT_EQ(parse_address(f->at("address")), r.range("scratch").begin);
        EXPECT_NE(f->at("message").get<std::string>().find("32 bytes of memory"), std::string::npos)
            << f->at("message");
    }
}

TEST_F(BugPrograms, ScratchOfTheQueriedSizeIsClean) {
    CAPTURE_AND_REPLAY(r, "scratch_too_small", "--fixed");
    expect_clean(r);
}

// The engine's rule (the stored pages give the bottom level's references no VUID for it): one
// finding per guessed reference that holds no CLAS; the first guess (offset 0) is right.
TEST_F(BugPrograms, BottomLevelOverGuessedImplicitAddressesReferencesNoClas) {
    CAPTURE_AND_REPLAY(r, "blas_guessed_addresses");
    EXPECT_TRUE(r.hazards().empty()) << r.describe();
    ASSERT_EQ(r.findings().size(), 2u) << r.describe();
    for (const json& f : r.findings()) {
        EXPECT_EQ(f.at("rule"), "CLASTRACE-cluster-reference-holds-no-clas");
        EXPECT_EQ(f.at("op_index"), 0);
        EXPECT_EQ(f.at("where").at("command"), 2);  // after the cluster build and the barrier
    }
    EXPECT_EQ(parse_address(r.findings().at(0).at("address")), r.range("guessed_second").begin);
    EXPECT_NE(r.findings().at(0).at("message").get<std::string>().find(
                  "srcInfosArray[0].clusterReferences[1]"),
              std::string::npos);
}

TEST_F(BugPrograms, BottomLevelOverTheWrittenAddressesIsClean) {
    CAPTURE_AND_REPLAY(r, "blas_guessed_addresses", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, InfosArrayShorterThanTheCountIsFound) {
    CAPTURE_AND_REPLAY(r, "infos_array_short");
    EXPECT_TRUE(r.hazards().empty()) << r.describe();
    const json* short_array = nullptr;
    for (const json& f : r.findings())
        if (f.at("rule") ==
            "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10454")
            short_array = &f;
    ASSERT_NE(short_array, nullptr) << r.describe();
    EXPECT_EQ(parse_address(short_array->at("address")), r.range("infos").begin);
    EXPECT_EQ(short_array->at("where").at("command"), 0);
    EXPECT_NE(short_array->at("message").get<std::string>().find("the op count is 3"),
              std::string::npos)
        << short_array->at("message");
}

TEST_F(BugPrograms, InfosArrayHoldingTheCountIsClean) {
    CAPTURE_AND_REPLAY(r, "infos_array_short", "--fixed");
    expect_clean(r);
}

// Session 17: the scratch sub-allocated over the src infos the same command reads. Every
// overlapping info is found (from op 4 on), at the first byte both share.
TEST_F(BugPrograms, ScratchSubAllocatedOverItsOwnInfosIsFoundPerOp) {
    CAPTURE_AND_REPLAY(r, "scratch_overlaps_infos");
    EXPECT_TRUE(r.hazards().empty()) << r.describe();
    ASSERT_FALSE(r.findings().empty()) << r.describe();
    const Range infos = r.range("infos"), scratch = r.range("scratch");
    for (const json& f : r.findings()) {
        EXPECT_EQ(f.at("rule"), "CLASTRACE-op-reads-what-another-op-writes");
        EXPECT_EQ(f.at("where").at("name"), kClusterBuild);
        EXPECT_NE(f.at("message").get<std::string>().find(
                      "which the command writes as scratchData"),
                  std::string::npos)
            << f.at("message");
        const uint64_t at = parse_address(f.at("address"));
        EXPECT_GE(at, scratch.begin);
        EXPECT_LT(at, std::min(infos.end, scratch.end));
    }
    // A finding of the whole command (no op of its own): the message names the op.
    EXPECT_NE(r.findings().at(0).at("message").get<std::string>().find(
                  "op 4 reads srcInfosArray[4]"),
              std::string::npos)
        << r.describe();
}

TEST_F(BugPrograms, ScratchAfterAllItsInfosIsClean) {
    CAPTURE_AND_REPLAY(r, "scratch_overlaps_infos", "--fixed");
    expect_clean(r);
}

}  // namespace
}  // namespace clastrace::bug_programs
