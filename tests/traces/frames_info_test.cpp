// SPDX-License-Identifier: Apache-2.0
// QueuePresent (format 1.2) without a GPU: `clastrace info` assigns each submission to the
// frame of the next present (after the last, to the frame after it), and `clastrace replay`
// accepts the record.
#include "shell_run.h"
#include "trace_test_support.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdio>


namespace clastrace::traces::testing {
namespace {

using ProgramRun = ShellRun;

ProgramRun run(const std::string& args) {
    return run_shell(std::string(CLASTRACE_BIN) + " " + args + " 2>&1");
}

fbs::RecordT present(uint64_t frame) {
    fbs::QueuePresentT p;
    p.queue = 0x9e;
    p.frame = frame;
    p.wait_semaphores = {0x5e0 + frame};
    p.swapchains = {0x5c};
    p.image_indices = {uint32_t(frame % 3)};
    fbs::RecordT r;
    r.body.Set(std::move(p));
    return r;
}

// A VkFrameBoundaryEXT of a headless program (format 1.4) ending `frame`, or with `frame_end`
// false a mark that ends nothing.
fbs::RecordT frame_mark(uint64_t frame, bool frame_end = true) {
    fbs::FrameBoundaryT m;
    m.queue = 0x9e;
    m.flags = frame_end ? 1u : 0u;  // VK_FRAME_BOUNDARY_FRAME_END_BIT_EXT
    m.frame_id = 100 + frame;
    m.frame = frame;
    fbs::RecordT r;
    r.body.Set(std::move(m));
    return r;
}

// The frame a layout character ends: a digit (present) or a..j (frame-end mark).
uint64_t ended_frame(char c) { return c >= 'a' ? uint64_t(c - 'a') : uint64_t(c - '0'); }

// `layout`: 'S' a submission (the last of its frame signalling semaphore 0x5e0 + the frame it
// belongs to: a second signal before the present's wait would be VUID-vkQueueSubmit-
// pSignalSemaphores-00067), a digit a present ending that frame, a..j a frame-end mark ending
// frame 0..9, 'x' a mark without the frame-end flag.
std::string write_trace(const std::string& name, const std::string& layout) {
    const std::string path = temp_path(name);
    TraceError error;
    auto w = TraceWriter::create(path, test_header(), {}, &error);
    EXPECT_TRUE(w) << error.message;
    if (!w) return path;
    for (size_t i = 0; i < layout.size(); ++i) {
        if (layout[i] == 'x') {
            EXPECT_FALSE(w->append(frame_mark(9, false)));
            continue;
        }
        if (layout[i] != 'S') {
            EXPECT_FALSE(w->append(layout[i] >= 'a' ? frame_mark(ended_frame(layout[i]))
                                                    : present(ended_frame(layout[i]))));
            continue;
        }
        // The frame this submission belongs to: the next present's, else the last one's + 1.
        uint64_t frame = 0;
        const size_t next = layout.find_first_not_of("Sx", i);
        if (next != std::string::npos)
            frame = ended_frame(layout[next]);
        else if (const size_t last = layout.find_last_not_of("Sx"); last != std::string::npos)
            frame = ended_frame(layout[last]) + 1;
        fbs::QueueSubmitT s;
        s.queue = 0x9e;
        s.version = 1;
        auto batch = std::make_unique<fbs::SubmitBatchT>();
        if (i + 1 == layout.size() || layout[i + 1] != 'S')
            batch->signal_semaphores.emplace_back(0x5e0 + frame, 0, 0, 0);
        s.batches.push_back(std::move(batch));
        s.submission_index = w->next_submission_index();
        fbs::RecordT r;
        r.body.Set(std::move(s));
        EXPECT_FALSE(w->append(r));
    }
    EXPECT_FALSE(w->finish());
    return path;
}

TEST(FramesInfo, SubmissionsBelongToTheNextPresentsFrame) {
    const std::string path = write_trace("frames.clt", "S56SS7S");
    ProgramRun json = run("info --json " + path);
    ASSERT_EQ(json.exit_code, 0) << json.output;
    const nlohmann::json j = nlohmann::json::parse(json.output);
    EXPECT_EQ(j["format_version"]["minor"],
              clastrace::traces::TraceReader::current_version_minor());  // what this build writes
    EXPECT_EQ(j["records"]["by_kind"]["QueuePresent"], 3);
    EXPECT_EQ(j["frames"]["presents"], 3);
    EXPECT_EQ(j["frames"]["first"], 5);
    EXPECT_EQ(j["frames"]["last"], 7);
    EXPECT_EQ(j["frames"]["with_submissions"],
              nlohmann::json::parse(
                  R"([{"frame": 5, "submissions": 1}, {"frame": 7, "submissions": 2},
                                        {"frame": 8, "submissions": 1}])"));
    ProgramRun text = run("info " + path);
    EXPECT_NE(
        text.output.find(
            "frames      3 presents, ending frames 5-7; submissions in frames: 5 (1) 7 (2) 8 (1)"),
        std::string::npos)
        << text.output;

    // Replay takes the presents' waits: each present consumes its frame's signal.
    ProgramRun replay = run("replay " + path);
    EXPECT_EQ(replay.exit_code, 0) << replay.output;
    EXPECT_NE(replay.output.find("submissions 4"), std::string::npos) << replay.output;
    std::remove(path.c_str());
}

// A headless program's frame-end marks end frames as presents do; a mark without the frame-end
// flag ends nothing.
TEST(FramesInfo, FrameEndMarksEndFramesLikePresents) {
    const std::string path = write_trace("marks.clt", "SaSSxbS");
    ProgramRun json = run("info --json " + path);
    ASSERT_EQ(json.exit_code, 0) << json.output;
    const nlohmann::json frames = nlohmann::json::parse(json.output)["frames"];
    EXPECT_EQ(frames["presents"], 0);
    EXPECT_EQ(frames["frame_marks"], 2);
    EXPECT_EQ(frames["first"], 0);
    EXPECT_EQ(frames["last"], 1);
    EXPECT_EQ(frames["with_submissions"], nlohmann::json::parse(R"([{"frame": 0, "submissions": 1},
                                        {"frame": 1, "submissions": 2},
                                        {"frame": 2, "submissions": 1}])"));
    ProgramRun text = run("info " + path);
    EXPECT_NE(text.output.find("frames      2 frame-end marks, ending frames 0-1; submissions in "
                               "frames: 0 (1) 1 (2) 2 (1)"),
              std::string::npos)
        << text.output;
    EXPECT_EQ(run("replay " + path).exit_code, 0);
    std::remove(path.c_str());
}

TEST(FramesInfo, PresentsWithoutSubmissionsAndNoPresentsAtAll) {
    const std::string onlyPresents = write_trace("presents.clt", "0123");
    ProgramRun text = run("info " + onlyPresents);
    EXPECT_EQ(text.exit_code, 0) << text.output;
    EXPECT_NE(text.output.find("4 presents, ending frames 0-3; submissions in frames: none"),
              std::string::npos)
        << text.output;

    const std::string noPresents = write_trace("nopresents.clt", "SS");
    ProgramRun json = run("info --json " + noPresents);
    ASSERT_EQ(json.exit_code, 0) << json.output;
    EXPECT_EQ(nlohmann::json::parse(json.output)["frames"],
              nlohmann::json::parse(R"({"presents": 0})"));
    EXPECT_EQ(run("info " + noPresents).output.find("frames "),
              std::string::npos);  // no frames line
    std::remove(onlyPresents.c_str());
    std::remove(noPresents.c_str());
}

}  // namespace
}  // namespace clastrace::traces::testing
