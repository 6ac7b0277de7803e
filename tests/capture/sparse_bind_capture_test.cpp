// SPDX-License-Identifier: Apache-2.0
// vkQueueBindSparse captured for real: tests/apps/sparse_capture_app builds clusters into a
// sparse buffer on lavapipe 25 (sparseBinding) under `clastrace capture` (the layer serves the
// extension and writes the engine's outputs through the memory bound under the sparse buffer),
// then `clastrace replay` checks the trace. Label rt-driver: skipped where lavapipe 25 is not
// unpacked.
#include "layer_launch_test.h"

#include <clastrace/engine/cluster_format.h>
#include <clastrace/testsupport/test_driver.h>
#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using namespace clastrace::layer_launch;

// One buffer bind of a QueueBindSparse record, flattened.
struct RecordedBind {
    uint64_t buffer = 0, device_address = 0, resource_offset = 0, size = 0, memory = 0,
             memory_offset = 0;
    size_t wait_semaphores = 0, signal_semaphores = 0;
};

class SparseBindCapture : public RayTracingLaunchTest {
protected:
    SparseBindCapture() : RayTracingLaunchTest("clastrace_sparse_e2e") {}

    void SetUp() override {
        RayTracingLaunchTest::SetUp();
        if (IsSkipped()) return;
        trace = dir / "sparse.clt";
    }

    // The app in `mode` under `clastrace capture` on lavapipe 25; its OUT.json is `out`.
    ProcessResult capture(const std::string& mode) {
        ProcessResult r = captureOnDriver(trace, std::string(CLASTRACE_SPARSE_APP) + " " + mode +
                                                     " " + quote((dir / "out.json").string()));
        if (r.exitCode == 0) out = json::parse(readText(dir / "out.json"));
        return r;
    }

    json replay() {
        ProcessResult r =
            run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " replay --json " + quote(trace.string()),
                {}, false);
        replayExitCode = r.exitCode;
        return json::parse(r.out);
    }

    std::vector<RecordedBind> recordedBinds() {
        clastrace::traces::TraceError error;
        auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
        EXPECT_TRUE(reader) << error.message;
        std::vector<RecordedBind> binds;
        if (!reader) return binds;
        clastrace::traces::RecordView view;
        while (reader->next(&view)) {
            if (view.kind != clastrace::fbs::RecordBody::QueueBindSparse) continue;
            const auto* call = view.record->body_as_QueueBindSparse();
            for (const auto* batch : *call->batches())
                for (const auto* buffer : *batch->buffer_binds())
                    for (const auto* m : *buffer->binds())
                        binds.push_back(
                            {buffer->buffer(), buffer->device_address(), m->resource_offset(),
                             m->size(), m->memory(), m->memory_offset(),
                             batch->wait_semaphores() ? batch->wait_semaphores()->size() : 0u,
                             batch->signal_semaphores() ? batch->signal_semaphores()->size() : 0u});
        }
        return binds;
    }

    void expectTheOneBindOfTheWholeBuffer(size_t signals) {
        const std::vector<RecordedBind> binds = recordedBinds();
        ASSERT_EQ(binds.size(), 1u);
        const json& s = out["sparse"];
        EXPECT_EQ(binds[0].buffer, s["buffer"].get<uint64_t>());
        EXPECT_EQ(binds[0].device_address, s["address"].get<uint64_t>());
        EXPECT_EQ(binds[0].resource_offset, 0u);
        EXPECT_EQ(binds[0].size, s["size"].get<uint64_t>());
        EXPECT_EQ(binds[0].memory, s["memory"].get<uint64_t>());
        EXPECT_EQ(binds[0].memory_offset, s["memoryOffset"].get<uint64_t>());
        EXPECT_EQ(binds[0].wait_semaphores, 0u);
        EXPECT_EQ(binds[0].signal_semaphores, signals);
    }

    fs::path trace;
    json out;
    int replayExitCode = -1;
};

std::vector<uint8_t> bytesOf(const json& hexText) {
    const std::string text = hexText.get<std::string>();
    std::vector<uint8_t> bytes(text.size() / 2);
    for (size_t i = 0; i < bytes.size(); ++i)
        bytes[i] = uint8_t(std::stoul(text.substr(2 * i, 2), nullptr, 16));
    return bytes;
}

// The bind signals a semaphore the builds wait on: the layer follows the bind, serves the builds
// into the memory under the sparse buffer, and the trace replays clean with every output equal.
TEST_F(SparseBindCapture, BoundBeforeTheBuildsCapturesAndReplaysClean) {
    ProcessResult r = capture("bound");
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
    expectTheOneBindOfTheWholeBuffer(1);

    // The served clusters reached the application through the sparse buffer's memory: each
    // address the build wrote lies in the sparse buffer and holds an engine object.
    const auto dstAddresses = bytesOf(out["buffers"]["dstAddresses"]["bytes"]);
    const auto implicit = bytesOf(out["buffers"]["implicitData"]["bytes"]);
    const uint64_t base = out["sparse"]["address"];
    for (uint32_t i = 0; i < 3; ++i) {
        uint64_t at;
        uint32_t magic;
        std::memcpy(&at, dstAddresses.data() + 8 * i, 8);
        ASSERT_GE(at, base) << i;
        ASSERT_LT(at - base + 4, implicit.size()) << i;
        std::memcpy(&magic, implicit.data() + (at - base), 4);
        EXPECT_EQ(magic, clastrace::engine::kObjectMagic) << i;
    }

    const json report = replay();
    EXPECT_EQ(replayExitCode, 0) << report.dump(1);
    EXPECT_TRUE(report["clean"].get<bool>()) << report.dump(1);
    EXPECT_TRUE(report["engine_trace"].get<bool>());
    EXPECT_TRUE(report["findings"].empty()) << report["findings"].dump(1);
    EXPECT_TRUE(report["hazards"]["hazards"].empty()) << report["hazards"].dump(1);
    EXPECT_EQ(report["counts"]["cluster_commands"].get<uint64_t>(), 2u);
    // The outputs both builds wrote (sizes, addresses, the objects in the sparse buffer) were
    // compared, and none differs (no CLASTRACE-replay-output-differs among the findings).
    EXPECT_GE(report["counts"]["outputs_compared"].get<uint64_t>(), 2u);
    EXPECT_GT(report["counts"]["output_bytes_compared"].get<uint64_t>(), 0u);
}

// The bug: the builds run before anything is bound under dstImplicitData (the bind comes after
// their submission). The replay places a sparse buffer at its first bind, so before it the
// buffer's addresses are no memory at all: each of the cluster build's three writes to
// dstImplicitData is a CLASTRACE-memory-fault (what follows from it, the bottom level over
// clusters that were never written, is reported too). It is not CLASTRACE-sparse-unbound-access,
// which covers unbound parts of a buffer already placed (docs/replay.md 'Sparse memory').
TEST_F(SparseBindCapture, BindAfterTheBuildsMakesTheirImplicitWritesFaults) {
    ProcessResult r = capture("bind-after-use");
    ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
    expectTheOneBindOfTheWholeBuffer(0);

    const json report = replay();
    EXPECT_EQ(replayExitCode, 1) << report.dump(1);
    EXPECT_FALSE(report["clean"].get<bool>());
    size_t implicitFaults = 0;
    for (const json& f : report["findings"]) {
        EXPECT_NE(f["rule"], "CLASTRACE-sparse-bind-damaged") << f.dump(1);
        if (f["rule"] == "CLASTRACE-memory-fault" &&
            f["message"].get<std::string>().find("field dstImplicitData[op ") != std::string::npos)
            ++implicitFaults;
    }
    EXPECT_EQ(implicitFaults, 3u) << report["findings"].dump(1);
    EXPECT_TRUE(report["hazards"]["hazards"].empty()) << report["hazards"].dump(1);
}

}  // namespace
