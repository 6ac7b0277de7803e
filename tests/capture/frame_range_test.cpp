// SPDX-License-Identifier: Apache-2.0
// CLASTRACE_FRAME_RANGE end to end: present_frames_app presents to an xcb window on an Xvfb
// display this test starts itself (lavapipe has no headless surface), under the layer on
// lavapipe, which serves the cluster extension. Frame f's builds carry clusterIDs
// 1000 * f + 500.., so the trace's srcInfosArray snapshots say which frames were captured.
#include "layer_launch_test.h"
#include <clastrace/testsupport/test_driver.h>
#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

namespace {

namespace fs = std::filesystem;
using clastrace::layer_launch::ProcessResult;
using clastrace::layer_launch::quote;
using clastrace::layer_launch::readText;
namespace fbs = clastrace::fbs;

const char* kXvfb = "/usr/bin/Xvfb";
constexpr uint32_t kFrameIdStride = 1000;  // present_frames_app's clusterID step per frame
constexpr uint32_t kTriangleClusterOp =
    2;  // VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV

// An Xvfb server on a display number it picks itself (-displayfd), for the whole suite.
class XvfbServer {
public:
    // Empty on success; otherwise why there is no display.
    std::string start() {
        if (access(kXvfb, X_OK) != 0)
            return std::string(kXvfb) +
                   " is missing: install xvfb (scripts/deps.sh lists it); the frame-range tests "
                   "present to an Xvfb window";
        int fds[2];
        if (pipe2(fds, O_CLOEXEC) != 0) return std::string("pipe: ") + std::strerror(errno);
        pid_ = fork();
        if (pid_ < 0) return std::string("fork: ") + std::strerror(errno);
        if (pid_ == 0) {
            prctl(PR_SET_PDEATHSIG,
                  SIGTERM);   // a test process that crashes leaves no server behind
            dup2(fds[1], 3);  // -displayfd 3: Xvfb writes the display number there once it listens
            const int devnull = open("/dev/null", O_WRONLY);
            dup2(devnull, 1);
            dup2(devnull, 2);
            execl(kXvfb, kXvfb, "-displayfd", "3", "-screen", "0", "320x240x24", "-nolisten", "tcp",
                  (char*)nullptr);
            _exit(127);
        }
        close(fds[1]);
        std::string number;
        pollfd p{fds[0], POLLIN, 0};
        char c = 0;
        while (poll(&p, 1, 20000) == 1 && read(fds[0], &c, 1) == 1 && c != '\n') number += c;
        close(fds[0]);
        if (number.empty()) {
            stop();
            return "Xvfb did not report a display number within 20 s";
        }
        display_ = ":" + number;
        return {};
    }
    void stop() {
        if (pid_ <= 0) return;
        kill(pid_, SIGTERM);
        int status = 0;
        waitpid(pid_, &status, 0);
        pid_ = -1;
    }
    const std::string& display() const { return display_; }

private:
    pid_t pid_ = -1;
    std::string display_;
};

XvfbServer xvfb;
std::string xvfbError;

// What a trace says about frames: presents, captured builds (by the frames their clusterIDs
// name), and the record order of submissions and presents.
struct FrameTrace {
    std::vector<uint64_t> presentFrames;
    std::vector<std::vector<uint64_t>> presentWaits;
    std::vector<std::vector<uint64_t>>
        submitSignals;               // per QueueSubmit, its batches' signal semaphores
    std::vector<std::string> order;  // "S" per QueueSubmit, "P<frame>" per QueuePresent
    // Format 1.2 acquires: "A" per AcquireNextImage too, with each acquire's semaphore, image and
    // result, and each submission's binary wait semaphores.
    std::vector<std::string> orderWithAcquires;
    std::vector<uint64_t> acquireSemaphores;
    std::vector<uint32_t> acquireImages;
    std::vector<int32_t> acquireResults;
    std::vector<std::vector<uint64_t>> presentImages;
    std::vector<std::vector<uint64_t>> submitWaits;
    std::multiset<uint32_t> triangleBuildFrames;
    uint32_t bottomLevelBuilds = 0;
    uint16_t versionMinor = 0;
    std::vector<std::string> problems;
};

FrameTrace readFrameTrace(const fs::path& path) {
    FrameTrace t;
    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(path.string(), &error);
    if (!reader) {
        t.problems.push_back(error.message);
        return t;
    }
    t.versionMinor = reader->version_minor();
    std::vector<std::pair<uint64_t, std::vector<fbs::MemorySnapshot>>>
        infos;  // srcInfosArray address, inputs
    clastrace::traces::RecordView view;
    while (reader->next(&view)) {
        const fbs::Record& r = *view.record;
        if (const auto* p = r.body_as_QueuePresent()) {
            t.presentFrames.push_back(p->frame());
            t.presentWaits.emplace_back();
            if (p->wait_semaphores())
                t.presentWaits.back().assign(p->wait_semaphores()->begin(),
                                             p->wait_semaphores()->end());
            t.order.push_back("P" + std::to_string(p->frame()));
            t.orderWithAcquires.push_back(t.order.back());
            t.presentImages.emplace_back();
            if (p->image_indices())
                t.presentImages.back().assign(p->image_indices()->begin(),
                                              p->image_indices()->end());
        } else if (const auto* a = r.body_as_AcquireNextImage()) {
            t.orderWithAcquires.push_back("A");
            t.acquireSemaphores.push_back(a->semaphore());
            t.acquireImages.push_back(a->image_index());
            t.acquireResults.push_back(a->result());
        } else if (const auto* s = r.body_as_QueueSubmit()) {
            t.order.push_back("S");
            t.orderWithAcquires.push_back("S");
            t.submitSignals.emplace_back();
            t.submitWaits.emplace_back();
            if (s->batches())
                for (const auto* b : *s->batches()) {
                    if (b->signal_semaphores())
                        for (const auto* op : *b->signal_semaphores())
                            t.submitSignals.back().push_back(op->semaphore());
                    if (b->wait_semaphores())
                        for (const auto* op : *b->wait_semaphores())
                            t.submitWaits.back().push_back(op->semaphore());
                }
        } else if (const auto* b = r.body_as_CmdBuildClusterAccelerationStructureIndirect()) {
            if (!b->input() || b->input()->op_type() != kTriangleClusterOp) {
                ++t.bottomLevelBuilds;
                continue;
            }
            std::vector<fbs::MemorySnapshot> inputs;
            if (b->inputs())
                for (const fbs::MemorySnapshot* snap : *b->inputs()) inputs.push_back(*snap);
            infos.emplace_back(b->src_infos_array() ? b->src_infos_array()->device_address() : 0,
                               std::move(inputs));
        }
    }
    for (const auto& e : reader->damage()) t.problems.push_back(e.message);
    // The first info's clusterID names the frame (read_contents ends the record walk above).
    for (const auto& [address, inputs] : infos) {
        bool found = false;
        for (const fbs::MemorySnapshot& snap : inputs) {
            if (address < snap.address() || address + 4 > snap.address() + snap.size()) continue;
            std::vector<uint8_t> bytes;
            if (auto e = reader->read_contents(snap.hash(), &bytes)) {
                t.problems.push_back(e.message);
                break;
            }
            uint32_t clusterId = 0;
            std::memcpy(&clusterId, bytes.data() + (address - snap.address()), 4);
            t.triangleBuildFrames.insert(clusterId / kFrameIdStride);
            found = true;
            break;
        }
        if (!found)
            t.problems.push_back("a triangle-cluster build without its srcInfosArray snapshot");
    }
    return t;
}

class FrameRange : public clastrace::layer_launch::LayerLaunchTest {
protected:
    FrameRange() : LayerLaunchTest("clastrace_frames") {}

    static void SetUpTestSuite() {
        if (clastrace::testsupport::test_driver().installed()) xvfbError = xvfb.start();
    }
    static void TearDownTestSuite() { xvfb.stop(); }

    void SetUp() override {
        LayerLaunchTest::SetUp();  // skips the test when the test driver is not installed
        if (IsSkipped()) return;
        ASSERT_TRUE(xvfbError.empty()) << xvfbError;
    }

    // Runs `command` on the Xvfb display with the test driver, the layer and `env` over a clean
    // CLASTRACE_* environment. These tests check which frames a range selects, so the state from
    // before the range is off (CLASTRACE_PRE_RANGE_STATE=0) unless a test turns it on.
    ProcessResult run(const std::string& command, std::map<std::string, std::string> env) {
        env["DISPLAY"] = xvfb.display();
        env.emplace("CLASTRACE_PRE_RANGE_STATE", "0");
        return LayerLaunchTest::run(command, std::move(env));
    }
    ProcessResult runApp(uint32_t frames, std::map<std::string, std::string> env,
                         uint32_t submissionsPerFrame = 1) {
        env["CLASTRACE_OUTPUT"] = (dir / "frames.clt").string();
        return run(std::string(CLASTRACE_PRESENT_APP) + " " + std::to_string(frames) + " " +
                       std::to_string(submissionsPerFrame),
                   env);
    }
    std::string cli(const std::string& args) { return std::string(CLASTRACE_CLI) + " " + args; }
};

const std::vector<uint64_t> kSixFrames = {0, 1, 2, 3, 4, 5};

TEST_F(FrameRange, CapturesExactlyTheBuildsOfTheSelectedFrames) {
    ProcessResult r = runApp(6, {{"CLASTRACE_FRAME_RANGE", "2-3"}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.out.find("presented 6 frames"), std::string::npos) << r.out;
    EXPECT_EQ(r.err, "");  // a valid range: nothing to say
    FrameTrace t = readFrameTrace(dir / "frames.clt");
    EXPECT_TRUE(t.problems.empty()) << t.problems.front();
    EXPECT_EQ(t.versionMinor, clastrace::traces::TraceReader::current_version_minor());
    // Every present is recorded, in or out of the range: frames 0..5 ended.
    EXPECT_EQ(t.presentFrames, kSixFrames);
    // Frames 2 and 3 only: one triangle-cluster build and one bottom level each.
    EXPECT_EQ(t.triangleBuildFrames, (std::multiset<uint32_t>{2, 3}));
    EXPECT_EQ(t.bottomLevelBuilds, 2u);
    // Each submission sits between the present that began its frame and the one that ended it.
    EXPECT_EQ(t.order, (std::vector<std::string>{"P0", "P1", "S", "P2", "S", "P3", "P4", "P5"}));
    // The present of a captured frame waits on the semaphore its submission signalled.
    ASSERT_EQ(t.submitSignals.size(), 2u);
    ASSERT_EQ(t.presentWaits.size(), 6u);
    ASSERT_EQ(t.submitSignals[0].size(), 1u);
    EXPECT_EQ(t.presentWaits[2], t.submitSignals[0]);
    EXPECT_EQ(t.presentWaits[3], t.submitSignals[1]);

    // The trace replays clean: every output byte equal, no hazard.
    ProcessResult replay = run(cli("replay " + quote((dir / "frames.clt").string())), {});
    EXPECT_EQ(replay.exitCode, 0) << replay.out << replay.err;
    EXPECT_NE(replay.out.find("result: clean"), std::string::npos) << replay.out;
    EXPECT_NE(replay.out.find("submissions 2,"), std::string::npos) << replay.out;

    // clastrace info counts the frames and the frames that hold submissions.
    ProcessResult info = run(cli("info --json " + quote((dir / "frames.clt").string())), {});
    ASSERT_EQ(info.exitCode, 0) << info.err;
    nlohmann::json frames = nlohmann::json::parse(info.out)["frames"];
    EXPECT_EQ(frames["presents"], 6);
    EXPECT_EQ(frames["first"], 0);
    EXPECT_EQ(frames["last"], 5);
    EXPECT_EQ(frames["with_submissions"],
              nlohmann::json::parse(
                  R"([{"frame": 2, "submissions": 1}, {"frame": 3, "submissions": 1}])"));
    EXPECT_EQ(nlohmann::json::parse(info.out)["records"]["by_kind"]["QueuePresent"], 6);
    ProcessResult text = run(cli("info " + quote((dir / "frames.clt").string())), {});
    EXPECT_NE(text.out.find("6 presents, ending frames 0-5; submissions in frames: 2 (1) 3 (1)"),
              std::string::npos)
        << text.out;
}

// With the state from before the range on (the default), the range's first submission is
// preceded by the prelude: frame 1's build, whose cluster and bottom level frame 2 may use, is
// kept and written ahead of it. The application waited for frame 1's fence, so the layer waits
// for that capture (it once stalled here for 10 s and wrote the prelude without its input bytes:
// the pause worker had taken the capture before the submission was noted as pre-range, so it
// never reached the prelude).
TEST_F(FrameRange, ThePreludeCarriesTheStateFromBeforeTheRange) {
    ProcessResult r =
        runApp(6, {{"CLASTRACE_FRAME_RANGE", "2-3"}, {"CLASTRACE_PRE_RANGE_STATE", "1"}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(r.err, "");  // no stall, no missing capture
    FrameTrace t = readFrameTrace(dir / "frames.clt");
    EXPECT_TRUE(t.problems.empty()) << t.problems.front();
    EXPECT_EQ(t.presentFrames, kSixFrames);
    // The prelude holds the last build of frame 1 (the kept cluster and bottom level): the
    // application waited for frame 1's fence, so the layer waits for its capture.
    EXPECT_EQ(t.triangleBuildFrames, (std::multiset<uint32_t>{1, 2, 3}));
    EXPECT_EQ(t.bottomLevelBuilds, 3u);
    EXPECT_EQ(t.order,
              (std::vector<std::string>{"P0", "P1", "S", "S", "P2", "S", "P3", "P4", "P5"}));
    ProcessResult replay = run(cli("replay " + quote((dir / "frames.clt").string())), {});
    EXPECT_EQ(replay.exitCode, 0) << replay.out << replay.err;
    EXPECT_NE(replay.out.find("result: clean"), std::string::npos) << replay.out;
    ProcessResult info = run(cli("info --json " + quote((dir / "frames.clt").string())), {});
    ASSERT_EQ(info.exitCode, 0) << info.err;
    const nlohmann::json state = nlohmann::json::parse(info.out)["frames"]["pre_range_state"];
    EXPECT_EQ(state.value("before_frame", 0), 2) << state;
    EXPECT_GT(state.value("bytes", 0), 0) << state;
}

TEST_F(FrameRange, WithoutARangeEveryFrameIsCaptured) {
    ProcessResult r = runApp(4, {});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    FrameTrace t = readFrameTrace(dir / "frames.clt");
    EXPECT_TRUE(t.problems.empty()) << t.problems.front();
    EXPECT_EQ(t.presentFrames, (std::vector<uint64_t>{0, 1, 2, 3}));
    EXPECT_EQ(t.triangleBuildFrames, (std::multiset<uint32_t>{0, 1, 2, 3}));
    EXPECT_EQ(t.order, (std::vector<std::string>{"S", "P0", "S", "P1", "S", "P2", "S", "P3"}));
    // Every binary signal is consumed by its present: replay finds nothing stale.
    ProcessResult replay = run(cli("replay " + quote((dir / "frames.clt").string())), {});
    EXPECT_EQ(replay.exitCode, 0) << replay.out << replay.err;
}

TEST_F(FrameRange, OpenEndedAndSingleFrameRanges) {
    ProcessResult r = runApp(5, {{"CLASTRACE_FRAME_RANGE", "3-"}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    FrameTrace t = readFrameTrace(dir / "frames.clt");
    EXPECT_EQ(t.triangleBuildFrames, (std::multiset<uint32_t>{3, 4}));
    EXPECT_EQ(t.presentFrames.size(), 5u);

    r = runApp(5, {{"CLASTRACE_FRAME_RANGE", "0"}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    t = readFrameTrace(dir / "frames.clt");
    EXPECT_EQ(t.triangleBuildFrames, (std::multiset<uint32_t>{0}));
    EXPECT_EQ(t.order.front(), "S");
}

// Three submissions a frame (two fills, then the build): frames are counted by presents, not
// by submissions, and a frame's every submission is captured.
TEST_F(FrameRange, AFrameIsEverySubmissionBetweenTwoPresents) {
    ProcessResult r = runApp(5, {{"CLASTRACE_FRAME_RANGE", "2-3"}}, 3);
    ASSERT_EQ(r.exitCode, 0) << r.err;
    FrameTrace t = readFrameTrace(dir / "frames.clt");
    EXPECT_TRUE(t.problems.empty()) << t.problems.front();
    EXPECT_EQ(t.triangleBuildFrames, (std::multiset<uint32_t>{2, 3}));
    EXPECT_EQ(t.order, (std::vector<std::string>{"P0", "P1", "S", "S", "S", "P2", "S", "S", "S",
                                                 "P3", "P4"}));
    ProcessResult replay = run(cli("replay " + quote((dir / "frames.clt").string())), {});
    EXPECT_EQ(replay.exitCode, 0) << replay.out << replay.err;
    EXPECT_NE(replay.out.find("submissions 6,"), std::string::npos) << replay.out;

    // The same frames by submission index: 6-11.
    r = runApp(5, {{"CLASTRACE_SUBMIT_RANGE", "6-11"}}, 3);
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(readFrameTrace(dir / "frames.clt").triangleBuildFrames,
              (std::multiset<uint32_t>{2, 3}));
    // Both: the frames 2-3 and the submissions 7-9 meet in frame 2's last submission (its build)
    // and frame 3's first two (fills only).
    r = runApp(5, {{"CLASTRACE_FRAME_RANGE", "2-3"}, {"CLASTRACE_SUBMIT_RANGE", "8-10"}}, 3);
    ASSERT_EQ(r.exitCode, 0) << r.err;
    t = readFrameTrace(dir / "frames.clt");
    EXPECT_EQ(t.triangleBuildFrames, (std::multiset<uint32_t>{2}));
    EXPECT_EQ(t.order, (std::vector<std::string>{"P0", "P1", "S", "P2", "S", "S", "P3", "P4"}));
}

// One submission per frame here, so submission k is frame k: the two ranges intersect.
TEST_F(FrameRange, BothRangesCaptureOnlyTheirIntersection) {
    ProcessResult r =
        runApp(6, {{"CLASTRACE_FRAME_RANGE", "1-4"}, {"CLASTRACE_SUBMIT_RANGE", "3-"}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    FrameTrace t = readFrameTrace(dir / "frames.clt");
    EXPECT_TRUE(t.problems.empty()) << t.problems.front();
    EXPECT_EQ(t.triangleBuildFrames, (std::multiset<uint32_t>{3, 4}));
    EXPECT_EQ(t.presentFrames, kSixFrames);
}

TEST_F(FrameRange, ABadValueIsNamedAndEveryFrameIsCaptured) {
    ProcessResult r = runApp(3, {{"CLASTRACE_FRAME_RANGE", "3-1"}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(
        r.err.find(
            "clastrace: CLASTRACE_FRAME_RANGE='3-1' is not N, A-B (A <= B) or A- (0-based frames); "
            "using the default"),
        std::string::npos)
        << r.err;
    FrameTrace t = readFrameTrace(dir / "frames.clt");
    EXPECT_EQ(t.triangleBuildFrames,
              (std::multiset<uint32_t>{0, 1, 2}));  // the default: all frames
}

TEST_F(FrameRange, CaptureCommandSetsTheRangeAndRejectsABadOne) {
    const std::string trace = (dir / "cli.clt").string();
    ProcessResult r =
        run(cli("capture -o " + quote(trace) + " --frames 4-5 -- " + CLASTRACE_PRESENT_APP + " 6"),
            {});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    FrameTrace t = readFrameTrace(trace);
    EXPECT_TRUE(t.problems.empty()) << t.problems.front();
    EXPECT_EQ(t.triangleBuildFrames, (std::multiset<uint32_t>{4, 5}));

    for (const char* bad : {"5-2", "x", "-3", "2-y", ""}) {
        ProcessResult b = run(cli("capture -o " + quote(trace) + " --frames " + quote(bad) +
                                  " -- " + CLASTRACE_PRESENT_APP + " 1"),
                              {});
        EXPECT_NE(b.exitCode, 0) << bad;
        EXPECT_NE(b.err.find("--frames"), std::string::npos) << bad << ": " << b.err;
        if (*bad) {
            EXPECT_NE(b.err.find(std::string("'") + bad + "' is not a frame range"),
                      std::string::npos)
                << b.err;
        }
        EXPECT_EQ(b.out.find("presented"), std::string::npos)
            << "the application ran despite --frames " << bad;
    }
    ProcessResult help = run(cli("capture --help"), {});
    EXPECT_NE(help.out.find("--frames"), std::string::npos);
    EXPECT_NE(help.out.find("vkQueuePresentKHR"), std::string::npos);
}

// vkAcquireNextImageKHR (format 1.2): one record per frame, before the frame's submission that
// waits on its semaphore, so replay finds every semaphore wait satisfied. Without the acquires
// (a trace of format 1.2 before them) each frame's wait has no signal in the trace: the
// replay_semaphore_tests twin WithoutAcquireRecordsEveryFramesWaitIsUnsatisfied shows the count
// is then the number of frames.
TEST_F(FrameRange, EveryAcquireIsRecordedBeforeItsFramesSubmission) {
    ProcessResult r = runApp(4, {});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    FrameTrace t = readFrameTrace(dir / "frames.clt");
    EXPECT_TRUE(t.problems.empty()) << t.problems.front();
    EXPECT_EQ(t.orderWithAcquires, (std::vector<std::string>{"A", "S", "P0", "A", "S", "P1", "A",
                                                             "S", "P2", "A", "S", "P3"}));
    ASSERT_EQ(t.acquireSemaphores.size(), 4u);
    ASSERT_EQ(t.submitWaits.size(), 4u);
    ASSERT_EQ(t.presentImages.size(), 4u);
    for (size_t f = 0; f < 4; ++f) {
        EXPECT_NE(t.acquireSemaphores[f], 0u);
        EXPECT_EQ(t.acquireResults[f], 0) << "frame " << f;
        // The frame's submission waits on what its acquire signalled; its present shows that image.
        EXPECT_EQ(t.submitWaits[f], std::vector<uint64_t>{t.acquireSemaphores[f]}) << "frame " << f;
        EXPECT_EQ(t.presentImages[f], std::vector<uint64_t>{t.acquireImages[f]}) << "frame " << f;
    }

    ProcessResult replay = run(cli("replay --json " + quote((dir / "frames.clt").string())), {});
    EXPECT_EQ(replay.exitCode, 0) << replay.out << replay.err;
    nlohmann::json counts = nlohmann::json::parse(replay.out)["counts"];
    EXPECT_EQ(counts["unsatisfied_semaphore_waits"], 0);
    EXPECT_EQ(counts["acquires"], 4);
    EXPECT_EQ(counts["presents"], 4);
    ProcessResult text = run(cli("replay " + quote((dir / "frames.clt").string())), {});
    EXPECT_NE(text.out.find(
                  "presents 4, acquires 4, semaphore waits with no signal in the trace 0"),
              std::string::npos)
        << text.out;

    ProcessResult info = run(cli("info --json " + quote((dir / "frames.clt").string())), {});
    ASSERT_EQ(info.exitCode, 0) << info.err;
    EXPECT_EQ(nlohmann::json::parse(info.out)["frames"]["acquires"], 4);
    EXPECT_EQ(nlohmann::json::parse(info.out)["records"]["by_kind"]["AcquireNextImage"], 4);
}

// Acquires are recorded in the selected frames only (their signals are consumed by submissions
// the range leaves out otherwise), so the range replays clean.
TEST_F(FrameRange, AcquiresAreRecordedInTheSelectedFramesOnly) {
    ProcessResult r = runApp(4, {{"CLASTRACE_FRAME_RANGE", "2"}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    FrameTrace t = readFrameTrace(dir / "frames.clt");
    EXPECT_EQ(t.orderWithAcquires, (std::vector<std::string>{"P0", "P1", "A", "S", "P2", "P3"}));
    ASSERT_EQ(t.submitWaits.size(), 1u);
    EXPECT_EQ(t.submitWaits[0], t.acquireSemaphores);
    ProcessResult replay = run(cli("replay --json " + quote((dir / "frames.clt").string())), {});
    EXPECT_EQ(replay.exitCode, 0) << replay.out << replay.err;
    nlohmann::json report = nlohmann::json::parse(replay.out);
    EXPECT_EQ(report["counts"]["unsatisfied_semaphore_waits"], 0);
    EXPECT_EQ(report["counts"]["acquires"], 1);
    EXPECT_TRUE(report["findings"].empty()) << report["findings"];
}

// The same with the state from before the range: frame 1's kept build goes into a prelude
// submission ahead of frame 2's, after frame 2's acquire (the application acquired before it
// submitted). The range's first submission waits on that acquire's semaphore.
TEST_F(FrameRange, AcquiresAndThePreludeOfASingleFrameRange) {
    ProcessResult r =
        runApp(4, {{"CLASTRACE_FRAME_RANGE", "2"}, {"CLASTRACE_PRE_RANGE_STATE", "1"}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(r.err, "");
    FrameTrace t = readFrameTrace(dir / "frames.clt");
    EXPECT_EQ(t.orderWithAcquires,
              (std::vector<std::string>{"P0", "P1", "A", "S", "S", "P2", "P3"}));
    EXPECT_EQ(t.triangleBuildFrames, (std::multiset<uint32_t>{1, 2}));
    ProcessResult replay = run(cli("replay --json " + quote((dir / "frames.clt").string())), {});
    EXPECT_EQ(replay.exitCode, 0) << replay.out << replay.err;
    nlohmann::json report = nlohmann::json::parse(replay.out);
    EXPECT_EQ(report["counts"]["unsatisfied_semaphore_waits"], 0);
    EXPECT_TRUE(report["findings"].empty()) << report["findings"];
}

// The debug JSON lists the presents too, with their swapchain, image and semaphores.
TEST_F(FrameRange, DebugJsonListsPresents) {
    ProcessResult r = run(std::string(CLASTRACE_PRESENT_APP) + " 3",
                          {{"CLASTRACE_DEBUG_JSON", (dir / "capture.json").string()},
                           {"CLASTRACE_FRAME_RANGE", "1"}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    nlohmann::json captured = nlohmann::json::parse(readText(dir / "capture.json"));
    ASSERT_EQ(captured["presents"].size(), 3u);
    for (uint64_t f = 0; f < 3; ++f) {
        const auto& p = captured["presents"][f];
        EXPECT_EQ(p["frame"], f);
        EXPECT_EQ(p["swapchains"].size(), 1u);
        EXPECT_EQ(p["imageIndices"].size(), 1u);
        EXPECT_EQ(p["waitSemaphores"].size(), 1u);
        EXPECT_EQ(p["result"], 0);
    }
    ASSERT_EQ(captured["submissions"].size(), 1u);
    EXPECT_EQ(captured["submissions"][0]["batches"][0]["signals"][0]["semaphore"],
              captured["presents"][1]["waitSemaphores"][0]);
    ASSERT_EQ(captured["acquires"].size(), 1u);  // frame 1's only
    EXPECT_EQ(captured["acquires"][0]["result"], 0);
    EXPECT_EQ(captured["acquires"][0]["imageIndex"], captured["presents"][1]["imageIndices"][0]);
}

}  // namespace
