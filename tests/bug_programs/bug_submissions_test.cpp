// SPDX-License-Identifier: Apache-2.0
// Bug programs whose commands run in different submissions, or whose host writes while the
// device may read: a semaphore, timeline value or fence that does not order them is a hazard,
// and its advice names the wait that missed.
#include "bug_programs_support.h"

#include <string>
#include <vector>

namespace clastrace::bug_programs {
namespace {

TEST_F(BugPrograms, BottomLevelInNextSubmissionReadsUnorderedAddressesAndObjects) {
    CAPTURE_AND_REPLAY(r, "blas_next_submission");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    expect_bottom_level_reads_unordered(r, 0, 1, 0, "pipeline_barrier");
}

TEST_F(BugPrograms, BottomLevelAfterSemaphoreIsClean) {
    CAPTURE_AND_REPLAY(r, "blas_next_submission", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, TimelineWaitOnEarlierValueLeavesBottomLevelUnordered) {
    CAPTURE_AND_REPLAY(r, "timeline_wrong_value");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    expect_bottom_level_reads_unordered(r, 1, 2, 0, "pipeline_barrier");
}

TEST_F(BugPrograms, TimelineWaitOnClusterBuildValueIsClean) {
    CAPTURE_AND_REPLAY(r, "timeline_wrong_value", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, HostRewriteBeforeFenceWaitIsHostWriteRace) {
    CAPTURE_AND_REPLAY(r, "host_rewrite_in_flight");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "WRITE-AFTER-READ");
    expect_side(h.at("prior"), kClusterBuild, 0, 0, "srcInfosArray", false);
    EXPECT_EQ(h.at("later").at("queue"), "host");
    EXPECT_EQ(h.at("later").at("write"), true);
    expect_inside(range_of(h.at("overlap")), r.range("infos"));
    EXPECT_EQ(h.at("fix").at("kind"), "host_wait");
    EXPECT_NE(h.at("message").get<std::string>().find("HOST-WRITE race"), std::string::npos);
}

TEST_F(BugPrograms, HostRewriteAfterFenceWaitIsClean) {
    CAPTURE_AND_REPLAY(r, "host_rewrite_in_flight", "--fixed");
    expect_clean(r);
}

// The same two reads as blas_next_submission, although a semaphore joins the submissions:
// its wait covers COMPUTE_SHADER only, not the bottom level's ACCELERATION_STRUCTURE_BUILD.
TEST_F(BugPrograms, SemaphoreWaitAtComputeStageLeavesBottomLevelUnordered) {
    CAPTURE_AND_REPLAY(r, "semaphore_wrong_stage");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    expect_bottom_level_reads_unordered(r, 0, 1, 0, "pipeline_barrier");
    for (const json& h : r.hazards())  // the advice names the wait that missed
        EXPECT_NE(h.at("fix").at("advice").get<std::string>().find(
                      "at COMPUTE_SHADER only: add ACCELERATION_STRUCTURE_BUILD"),
                  std::string::npos)
            << h.at("fix").at("advice");
}

TEST_F(BugPrograms, SemaphoreWaitAtBuildStageIsClean) {
    CAPTURE_AND_REPLAY(r, "semaphore_wrong_stage", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, HostRewriteAfterWaitingTheEarlierFrameFenceIsHostWriteRace) {
    CAPTURE_AND_REPLAY(r, "wrong_fence_host_rewrite");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "WRITE-AFTER-READ");
    expect_side(h.at("prior"), kClusterBuild, 1, 0, "srcInfosArray", false);
    EXPECT_EQ(h.at("later").at("queue"), "host");
    EXPECT_EQ(h.at("later").at("write"), true);
    expect_inside(range_of(h.at("overlap")), r.range("infos"));
    EXPECT_EQ(h.at("fix").at("kind"), "host_wait");
    EXPECT_NE(h.at("fix").at("advice").get<std::string>().find(
                  "signaled by submission 0, which does not include submission 1"),
              std::string::npos)
        << h.at("fix").at("advice");
}

TEST_F(BugPrograms, HostRewriteAfterWaitingTheBuildFenceIsClean) {
    CAPTURE_AND_REPLAY(r, "wrong_fence_host_rewrite", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, BottomLevelSubmittedBeforeItsClustersIsWriteAfterRead) {
    CAPTURE_AND_REPLAY(r, "blas_before_clas_submission");
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "WRITE-AFTER-READ");
    expect_side(h.at("prior"), kClusterBuild, 0, 0, "srcInfosArray[0].clusterReferences", false);
    expect_side(h.at("later"), kClusterBuild, 1, 0, "dstAddressesArray", true);
    expect_equal(range_of(h.at("overlap")), r.range("clas_addresses"));
    // The engine's findings on what the bottom level read: the addresses, still zero. 10484
    // says "All cluster references in clusterReferences must be unique" and leaves 0 no
    // exception, so the three zeros are two repeats, each naming the pair it saw.
    int unbuilt = 0;
    std::vector<std::string> repeats;
    for (const json& f : r.findings()) {
        if (f.at("rule") == "CLASTRACE-cluster-reference-holds-no-clas") {
            ++unbuilt;
            EXPECT_NE(f.at("message").get<std::string>().find("address is 0, not a CLAS"),
                      std::string::npos)
                << f.at("message");
        } else {
            EXPECT_EQ(f.at("rule"),
                      "VUID-VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV-"
                      "clusterReferences-10484");
            repeats.push_back(f.at("message").get<std::string>());
        }
    }
    EXPECT_EQ(unbuilt, 3) << r.describe();
    ASSERT_EQ(repeats.size(), 2u) << r.describe();
    EXPECT_NE(repeats[0].find("[0] and [1] both reference 0x0"), std::string::npos) << repeats[0];
    EXPECT_NE(repeats[1].find("[1] and [2] both reference 0x0"), std::string::npos) << repeats[1];
}

TEST_F(BugPrograms, BottomLevelSubmittedAfterItsClustersIsClean) {
    CAPTURE_AND_REPLAY(r, "blas_before_clas_submission", "--fixed");
    expect_clean(r);
}

// Session 17: vkQueueSubmit2's per-semaphore stage masks (a narrow signal), and a host signal.
TEST_F(BugPrograms, TimelineWaitAtComputeStageLeavesBottomLevelUnordered) {
    CAPTURE_AND_REPLAY(r, "timeline_submit2_wrong_stage");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    expect_bottom_level_reads_unordered(r, 0, 1, 0, "pipeline_barrier");
    for (const json& h : r.hazards())
        EXPECT_NE(h.at("fix").at("advice").get<std::string>().find(
                      "follows submission 0's access, but at COMPUTE_SHADER only: add "
                      "ACCELERATION_STRUCTURE_BUILD to the wait's stage mask"),
                  std::string::npos)
            << h.at("fix").at("advice");
}

TEST_F(BugPrograms, TimelineSignalAtCopyStageLeavesBottomLevelUnordered) {
    CAPTURE_AND_REPLAY(r, "timeline_submit2_wrong_stage", "--signal-copy");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    expect_bottom_level_reads_unordered(r, 0, 1, 0, "pipeline_barrier");
    for (const json& h : r.hazards())
        EXPECT_NE(h.at("fix").at("advice").get<std::string>().find(
                      "by submission 0, which submission 1 waits on, is at COPY only: add "
                      "ACCELERATION_STRUCTURE_BUILD to the signal's stage mask"),
                  std::string::npos)
            << h.at("fix").at("advice");
}

TEST_F(BugPrograms, TimelineAtBuildStageBothSidesIsClean) {
    CAPTURE_AND_REPLAY(r, "timeline_submit2_wrong_stage", "--fixed");
    expect_clean(r);
}

TEST_F(BugPrograms, HostWriteAfterItsHostSignalIsHostWriteRace) {
    CAPTURE_AND_REPLAY(r, "host_signal_before_write");
    EXPECT_TRUE(r.findings().empty()) << r.describe();
    ASSERT_EQ(r.hazards().size(), 1u) << r.describe();
    const json& h = r.hazards().at(0);
    EXPECT_EQ(h.at("class"), "WRITE-AFTER-READ");
    expect_side(h.at("prior"), kClusterBuild, 0, 0, "srcInfosArray", false);
    EXPECT_EQ(h.at("later").at("queue"), "host");
    expect_equal(range_of(h.at("overlap")), r.range("infos"));
}

}  // namespace
}  // namespace clastrace::bug_programs
