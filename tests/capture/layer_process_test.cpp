// SPDX-License-Identifier: Apache-2.0
// The layer as the loader loads it: VK_ADD_LAYER_PATH points at the build tree's manifest,
// VK_INSTANCE_LAYERS enables it, lavapipe is the driver (it lacks the cluster extension, so
// the layer serves it). Each test runs a program and asserts on what it and the layer wrote.
#include "layer_launch_test.h"
#include "served_scene.h"

#include <clastrace/common/hex.h>
#include <clastrace/engine/build_sizes.h>
#include <clastrace/engine/cluster_format.h>
#include <clastrace/engine/execute.h>
#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <cstring>
#include <span>

namespace {

namespace fs = std::filesystem;
using nlohmann::json;

using namespace clastrace::layer_launch;

class LayerProcess : public LayerLaunchTest {
protected:
    LayerProcess() : LayerLaunchTest("clastrace_capture") {}

    std::string app(const std::string& args) {
        return std::string(CLASTRACE_CAPTURE_APP) + " " + args;
    }
};

// ---- Serving ------------------------------------------------------------------------------

// vulkaninfo's lines listing the served extension at spec version 4 among the device's
// extensions: one tab in (the layer's own list is three tabs in), padded to the driver's
// longest extension name, which differs between drivers.
size_t served_extension_lines(const std::string& vulkaninfo) {
    const std::regex line("(^|\n)\tVK_NV_cluster_acceleration_structure +: extension revision 4");
    return std::distance(std::sregex_iterator(vulkaninfo.begin(), vulkaninfo.end(), line),
                         std::sregex_iterator());
}

TEST_F(LayerProcess, VulkaninfoListsTheServedExtension) {
    if (std::system("command -v vulkaninfo >/dev/null 2>&1") != 0)
        GTEST_SKIP() << "vulkaninfo is not installed";
    ProcessResult with = run("vulkaninfo", {});
    ASSERT_EQ(with.exitCode, 0) << with.err;
    EXPECT_NE(with.out.find("VK_LAYER_CLASTRACE_capture"), std::string::npos);
    // Listed among the device's extensions (and the layer's own), at spec version 4.
    EXPECT_EQ(served_extension_lines(with.out), 1u) << with.out;
    EXPECT_NE(with.out.find("llvmpipe"), std::string::npos);

    ProcessResult without = run("vulkaninfo", {}, false);
    ASSERT_EQ(without.exitCode, 0) << without.err;
    EXPECT_EQ(without.out.find("VK_NV_cluster_acceleration_structure"), std::string::npos);

    ProcessResult off = run("vulkaninfo", {{"CLASTRACE_SERVE", "0"}});
    ASSERT_EQ(off.exitCode, 0) << off.err;
    EXPECT_EQ(served_extension_lines(off.out), 0u);
}

TEST_F(LayerProcess, FeaturesPropertiesAndBuildSizesAreServed) {
    ProcessResult r = run(app("limits " + (dir / "limits.json").string()), {});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    json limits = json::parse(readText(dir / "limits.json"));
    EXPECT_TRUE(limits["extensionListed"].get<bool>());
    EXPECT_TRUE(limits["clusterAccelerationStructure"].get<bool>());
    EXPECT_NE(limits["deviceName"].get<std::string>().find("llvmpipe"), std::string::npos);
    const json& p = limits["properties"];
    EXPECT_EQ(p["maxVerticesPerCluster"], 256);
    EXPECT_EQ(p["maxTrianglesPerCluster"], 256);
    EXPECT_EQ(p["clusterScratchByteAlignment"], 128);
    EXPECT_EQ(p["clusterByteAlignment"], 128);
    EXPECT_EQ(p["clusterTemplateByteAlignment"], 32);
    EXPECT_EQ(p["clusterBottomLevelByteAlignment"], 256);
    EXPECT_EQ(p["clusterTemplateBoundsByteAlignment"], 32);
    EXPECT_EQ(p["maxClusterGeometryIndex"], 16777215);
    // 8 clusters of up to 128 triangles and vertices: at least their raw positions and indices.
    EXPECT_GE(limits["buildSizes"]["accelerationStructureSize"].get<uint64_t>(),
              1024u * 12 + 1024u * 3);
    EXPECT_GT(limits["buildSizes"]["buildScratchSize"].get<uint64_t>(), 0u);
}

TEST_F(LayerProcess, ServeOffLeavesTheDriverAsItIs) {
    ProcessResult r =
        run(app("limits " + (dir / "limits.json").string()), {{"CLASTRACE_SERVE", "0"}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    json limits = json::parse(readText(dir / "limits.json"));
    EXPECT_FALSE(limits["extensionListed"].get<bool>());
    EXPECT_FALSE(limits["clusterAccelerationStructure"].get<bool>());
    EXPECT_EQ(limits["properties"]["maxVerticesPerCluster"], 0);
}

// ---- Served builds execute in the engine ---------------------------------------------------

class ServeRun : public LayerProcess {
protected:
    json out;  // what cluster_capture_app `serve` read back after vkQueueWaitIdle

    static std::string hexOf(std::span<const std::byte> bytes) {
        return clastrace::common::hex_bytes(bytes);
    }
    static std::vector<uint8_t> bytesOf(const std::string& hex) {
        std::vector<uint8_t> bytes(hex.size() / 2);
        for (size_t i = 0; i < bytes.size(); ++i)
            bytes[i] = uint8_t(std::stoul(hex.substr(2 * i, 2), nullptr, 16));
        return bytes;
    }
    ProcessResult runServe(std::map<std::string, std::string> env = {}) {
        ProcessResult r = run(app("serve " + (dir / "serve.json").string()), env);
        if (r.exitCode == 0) out = json::parse(readText(dir / "serve.json"));
        return r;
    }
    uint64_t address(const char* name) const { return out["buffers"][name]["address"]; }

    // The room the served bottom level's implicit object took: what the application read back
    // from its dstSizesArray. Where the layer makes cluster BLASes traceable (lavapipe 25, the
    // default mode) that is the driver's room (engine::ExecuteOptions::implicit_object_room);
    // elsewhere the object's own size, which as a room changes nothing.
    uint64_t blasRoom() const {
        const auto sizes = bytesOf(out["buffers"]["blasDstSizes"]["bytes"]);
        uint32_t room = 0;
        std::memcpy(&room, sizes.data(), 4);
        return room;
    }

    // The same two commands run by engine::execute on the host, at the application's addresses,
    // over buffers holding what the application wrote into them (0xEE elsewhere), the bottom
    // level given the room the layer gave it (blasRoom); every buffer the application read back
    // must equal the engine's, byte for byte, but for a traceable bottom level's room, which
    // holds the driver's BVH (capture/README.md "Traceable cluster BLASes").
    void expectTheEnginesBytes() {
        served_scene::Addresses a{address("vertices"),     address("indices"),
                                  address("infos"),        address("counts"),
                                  address("dstAddresses"), address("dstSizes"),
                                  address("implicitData"), address("scratch"),
                                  address("blasInfos"),    address("blasDstAddresses"),
                                  address("blasDstSizes"), address("blasImplicit"),
                                  address("blasScratch")};
        clastrace::engine::MemoryImage image;
        for (const auto& [name, b] : out["buffers"].items()) {
            auto& region = image.add_region(b["address"], b["size"], 0, name);
            std::fill(region.bytes.begin(), region.bytes.end(), std::byte{0xEE});
        }
        served_scene::Inputs in = served_scene::makeInputs(a);
        auto put = [&](uint64_t at, const void* data, size_t size) {
            std::memcpy(image.write_bytes(at, size, {}).data(), data, size);
        };
        put(a.vertices, in.vertices.data(), in.vertices.size() * 4);
        put(a.indices, in.indices.data(), in.indices.size() * 4);
        put(a.infos, in.infos.data(), in.infos.size() * served_scene::kInfoStride);
        put(a.counts, in.counts, sizeof in.counts);
        put(a.blasInfos, &in.blasInfo, sizeof in.blasInfo);
        served_scene::Commands commands;
        served_scene::makeCommands(a, commands);
        clastrace::engine::ObjectDirectory directory;
        clastrace::engine::ExecuteOptions options;
        options.directory = &directory;
        uint64_t driverRoom = 0;  // bytes of blasImplicit that hold the driver's BVH
        for (auto [command, name] :
             {std::pair{&commands.clusters, "clusters"}, std::pair{&commands.blas, "blas"}}) {
            const bool blas = command == &commands.blas;
            options.implicit_object_room = blas ? blasRoom() : 0;
            auto record = clastrace::engine::execute(*command, image, options);
            EXPECT_EQ(record.findings.size(), 0u) << record.findings[0].message;
            if (blas && !record.ops.empty() && record.ops[0].dst_size < blasRoom())
                driverRoom = blasRoom();
            // What the application was told through the loader is the engine's bound, or the
            // objects' rooms where more, and holds the build.
            const auto bound =
                clastrace::engine::cluster_build_sizes(command->input,
                                                       clastrace::engine::EngineProperties{});
            const json& told = out["buildSizes"][name];
            EXPECT_EQ(told["accelerationStructureSize"].get<uint64_t>(),
                      std::max<uint64_t>(bound.acceleration_structure_size,
                                         uint64_t(command->input.maxAccelerationStructureCount) *
                                             options.implicit_object_room))
                << name;
            EXPECT_EQ(told["buildScratchSize"].get<uint64_t>(), bound.build_scratch_size) << name;
            EXPECT_GT(record.implicit_bytes_used, 0u) << name;
            EXPECT_LE(record.implicit_bytes_used, told["accelerationStructureSize"].get<uint64_t>())
                << name;
            EXPECT_LE(record.scratch_bytes_used, bound.build_scratch_size) << name;
        }
        for (const auto& [name, b] : out["buffers"].items()) {
            std::string want = hexOf(image.read_bytes(b["address"], b["size"], {}));
            std::string got = b["bytes"].get<std::string>();
            if (name == "blasImplicit" && driverRoom) {  // the driver's BVH from its start
                const size_t hole = std::min<size_t>(2 * driverRoom, want.size());
                EXPECT_NE(got.substr(0, hole), want.substr(0, hole)) << "no driver BVH";
                want.erase(0, hole);
                got.erase(0, std::min(hole, got.size()));
            }
            EXPECT_EQ(got, want) << name;
        }

        // And what that means: sizes > 0, addresses inside dstImplicitData at the advertised
        // alignment, objects that start with the engine's magic.
        const auto dstAddresses = bytesOf(out["buffers"]["dstAddresses"]["bytes"]);
        const auto dstSizes = bytesOf(out["buffers"]["dstSizes"]["bytes"]);
        const auto implicit = bytesOf(out["buffers"]["implicitData"]["bytes"]);
        const uint64_t alignment = out["properties"]["clusterByteAlignment"];
        for (uint32_t i = 0; i < served_scene::kClusterCount; ++i) {
            uint64_t at;
            uint32_t size, magic;
            std::memcpy(&at, dstAddresses.data() + 8 * i, 8);
            std::memcpy(&size, dstSizes.data() + 4 * i, 4);
            EXPECT_GT(size, 0u);
            EXPECT_EQ(at % alignment, 0u);
            ASSERT_GE(at, a.implicitData);
            ASSERT_LE(at - a.implicitData + size, implicit.size());
            std::memcpy(&magic, implicit.data() + (at - a.implicitData), 4);
            EXPECT_EQ(magic, clastrace::engine::kObjectMagic);
        }
        const auto blasAddress = bytesOf(out["buffers"]["blasDstAddresses"]["bytes"]);
        uint64_t blas;
        std::memcpy(&blas, blasAddress.data(), 8);
        EXPECT_EQ(blas % out["properties"]["clusterBottomLevelByteAlignment"].get<uint64_t>(), 0u);
        EXPECT_EQ(blas, a.blasImplicit);
    }
};

TEST_F(ServeRun, BuildsWriteWhatTheEngineComputesAndTheCaptureRecordsIt) {
    ProcessResult r = runServe({{"CLASTRACE_DEBUG_JSON", (dir / "capture.json").string()}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(r.err, "");  // no findings: the scene is valid
    expectTheEnginesBytes();

    // The capture's outputs are the bytes the engine wrote (read after the command, and
    // what the application saw at the end, nothing overwrote them).
    json captured = json::parse(readText(dir / "capture.json"));
    ASSERT_EQ(captured["clusterBuilds"].size(), 2u);
    for (const auto& build : captured["clusterBuilds"]) {
        EXPECT_TRUE(build["executedByEngine"].get<bool>());
        EXPECT_TRUE(build["engineFindings"].empty()) << build["engineFindings"];
    }
    bool sawSizes = false;
    for (const auto& range : captured["clusterBuilds"][0]["outputs"])
        if (range["role"] == "dstSizes") {
            sawSizes = true;
            EXPECT_EQ(range["address"], address("dstSizes"));
            EXPECT_EQ(range["bytes"].get<std::string>(),
                      out["buffers"]["dstSizes"]["bytes"].get<std::string>().substr(
                          0, 8 * served_scene::kClusterCount));
        }
    EXPECT_TRUE(sawSizes);
}

TEST_F(ServeRun, CaptureOffStillExecutesTheBuilds) {
    ProcessResult r = runServe({{"CLASTRACE_CAPTURE", "0"}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    expectTheEnginesBytes();
}

TEST_F(ServeRun, ServeOffLeavesTheApplicationWithoutTheExtension) {
    ProcessResult r = runServe({{"CLASTRACE_SERVE", "0"}});
    EXPECT_EQ(r.exitCode, 3) << r.err;
    EXPECT_NE(r.out.find("VK_NV_cluster_acceleration_structure is not supported"),
              std::string::npos)
        << r.out;
    EXPECT_FALSE(fs::exists(dir / "serve.json"));
}

// The trace says whose outputs it holds: the header's driver is clastrace's engine, and the
// builds' output snapshots hold the bytes the application read back.
TEST_F(ServeRun, TraceNamesTheEngineAsTheDriverOfItsOutputs) {
    const fs::path trace = dir / "serve.clt";
    ProcessResult r = runServe({{"CLASTRACE_OUTPUT", trace.string()}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    expectTheEnginesBytes();  // so the snapshots below are the engine's bytes
    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
    ASSERT_TRUE(reader) << error.message;
    ASSERT_TRUE(reader->header() && reader->header()->device() &&
                reader->header()->device()->driver_name());
    EXPECT_EQ(reader->header()->device()->driver_name()->str(), "clastrace engine");
    std::vector<std::pair<uint64_t, uint64_t>> outputs;  // (address, hash) of the first build
    clastrace::traces::RecordView view;
    while (reader->next(&view)) {
        if (view.kind != clastrace::fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect)
            continue;
        const auto* build = view.record->body_as_CmdBuildClusterAccelerationStructureIndirect();
        if (outputs.empty() && build->outputs())
            for (const auto* s : *build->outputs()) outputs.emplace_back(s->address(), s->hash());
    }
    bool sawSizes = false;
    for (const auto& [at, hash] : outputs) {
        if (at != address("dstSizes")) continue;
        sawSizes = true;
        std::vector<uint8_t> bytes;
        auto e = reader->read_contents(hash, &bytes);
        ASSERT_FALSE(e) << e.message;
        EXPECT_EQ(hexOf(std::as_bytes(std::span(bytes))),
                  out["buffers"]["dstSizes"]["bytes"].get<std::string>().substr(
                      0, 8 * served_scene::kClusterCount));
    }
    EXPECT_TRUE(sawSizes);
}

// ---- Capture at the point of execution -------------------------------------------------

class ExactnessRun : public LayerProcess {
protected:
    json expected, captured;
    void runExactness(std::map<std::string, std::string> env = {}) {
        env.emplace("CLASTRACE_DEBUG_JSON", (dir / "capture.json").string());
        ProcessResult r = run(app("exactness " + (dir / "expected.json").string()), env);
        ASSERT_EQ(r.exitCode, 0) << r.err;
        expected = json::parse(readText(dir / "expected.json"));
        if (fs::exists(dir / "capture.json"))
            captured = json::parse(readText(dir / "capture.json"));
    }
    static std::vector<json> ranges(const json& build, const std::string& role,
                                    const char* list = "inputs") {
        std::vector<json> out;
        for (const auto& r : build[list])
            if (r["role"] == role) out.push_back(r);
        return out;
    }
    static void expectRanges(const json& build, const std::string& role, const json& want) {
        auto got = ranges(build, role);
        ASSERT_EQ(got.size(), want.size()) << role;
        for (size_t i = 0; i < got.size(); ++i) {
            EXPECT_EQ(got[i]["address"], want[i]["address"]) << role << " #" << i;
            EXPECT_EQ(got[i]["bytes"], want[i]["bytes"]) << role << " #" << i;
        }
    }
};

TEST_F(ExactnessRun, CapturedBytesAreWhatTheQueueWroteBeforeTheBuild) {
    runExactness();
    ASSERT_EQ(captured["clusterBuilds"].size(), 2u);
    const json& build = captured["clusterBuilds"][0];
    const json& want = expected["clusterBuild"];
    EXPECT_EQ(build["executedCount"],
              2);  // min(srcInfosCount = 2 written by vkCmdFillBuffer, max 3)
    expectRanges(build, "srcInfosCount", json::array({want["srcInfosCount"]}));
    expectRanges(build, "srcInfos",
                 want["srcInfos"]);  // arrived by vkCmdUpdateBuffer + vkCmdCopyBuffer
    expectRanges(build, "indexBuffer", want["indexBuffer"]);
    expectRanges(build, "vertexBuffer", want["vertexBuffer"]);
    expectRanges(build, "geometryIndexAndFlagsBuffer", want["geometryIndexAndFlagsBuffer"]);
    // The memory ended up different (overwritten after the build in the same command buffer):
    // the capture is of the moment of execution, not of submission or completion.
    EXPECT_NE(expected["finalMemory"]["srcInfosCount"]["bytes"], want["srcInfosCount"]["bytes"]);
    EXPECT_NE(expected["finalMemory"]["vertexBuffer"]["bytes"], want["vertexBuffer"][0]["bytes"]);
    for (const auto& r : build["inputs"])
        EXPECT_EQ(r["bytes"].get<std::string>().find("eeee"), std::string::npos) << r;

    // Outputs are read right after the command, before the command buffer's later fill. The
    // layer serves the extension on lavapipe, so the engine wrote the two sizes over the
    // application's 0x77 fill.
    auto sizes = ranges(build, "dstSizes", "outputs");
    ASSERT_EQ(sizes.size(), 1u);
    const std::string sizeBytes = sizes[0]["bytes"];
    ASSERT_EQ(sizeBytes.size(), 16u);
    EXPECT_NE(sizeBytes, want["dstSizesAfter"]["bytes"]);
    EXPECT_NE(sizeBytes.substr(0, 8), "00000000");
    EXPECT_NE(sizeBytes.substr(8, 8), "00000000");
    EXPECT_NE(expected["finalMemory"]["dstSizes"]["bytes"], sizeBytes);
    EXPECT_TRUE(build["executedByEngine"].get<bool>());
    // The app's buffers lack the acceleration-structure usages the extension requires: the
    // engine's findings name the VUIDs and reach the capture.
    std::vector<std::string> rules;
    for (const auto& f : build["engineFindings"]) rules.push_back(f["rule"]);
    EXPECT_NE(
        std::find(rules.begin(), rules.end(),
                  "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-12305"),
        rules.end())
        << build["engineFindings"];

    const json& blas = captured["clusterBuilds"][1];
    const json& wantBlas = expected["bottomLevelBuild"];
    EXPECT_EQ(blas["executedCount"], 1);
    expectRanges(blas, "srcInfosCount", json::array({wantBlas["srcInfosCount"]}));
    expectRanges(blas, "srcInfos", wantBlas["srcInfos"]);
    expectRanges(blas, "clusterReferences", wantBlas["clusterReferences"]);
    EXPECT_TRUE(blas["issues"].empty()) << blas["issues"];
}

TEST_F(ExactnessRun, RecordsParametersCommandsStateAndSubmission) {
    runExactness();
    const json& build = captured["clusterBuilds"][0];
    const json& parameters = build["parameters"];
    EXPECT_EQ(parameters["maxAccelerationStructureCount"], 3);
    EXPECT_EQ(parameters["opType"], 2);
    EXPECT_EQ(parameters["srcInfosArray"][1], 80);
    EXPECT_EQ(parameters["triangleClusterInput"]["vertexFormat"],
              106);  // VK_FORMAT_R32G32B32_SFLOAT
    EXPECT_EQ(parameters["triangleClusterInput"]["maxTotalVertexCount"], 7);
    EXPECT_EQ(
        captured["clusterBuilds"][1]["parameters"]["bottomLevelInput"]["maxTotalClusterCount"], 2);

    // The application's commands, in order, without the layer's injected pause commands.
    ASSERT_EQ(captured["commandBuffers"].size(), 1u);
    std::vector<std::string> kinds;
    for (const auto& c : captured["commandBuffers"][0]["commands"]) kinds.push_back(c["kind"]);
    const std::vector<std::string> want = {"FillBuffer",
                                           "FillBuffer",
                                           "UpdateBuffer",
                                           "PipelineBarrier",
                                           "CopyBuffer",
                                           "UpdateBuffer",
                                           "UpdateBuffer",
                                           "UpdateBuffer",
                                           "UpdateBuffer",
                                           "UpdateBuffer",
                                           "UpdateBuffer",
                                           "UpdateBuffer",
                                           "FillBuffer",
                                           "PipelineBarrier",
                                           "BuildClusterAccelerationStructureIndirectNV",
                                           "BuildClusterAccelerationStructureIndirectNV",
                                           "PipelineBarrier",
                                           "FillBuffer",
                                           "FillBuffer",
                                           "FillBuffer",
                                           "FillBuffer"};
    EXPECT_EQ(kinds, want);
    EXPECT_EQ(captured["commandBuffers"][0]["commands"][0]["data"], 2);

    ASSERT_EQ(captured["submissions"].size(), 1u);
    EXPECT_NE(captured["submissions"][0]["fence"], 0);
    EXPECT_EQ(captured["submissions"][0]["batches"][0]["commandBuffers"][0],
              captured["commandBuffers"][0]["commandBuffer"]);

    // State: 11 buffers with their usage, bound and addressed; host-visible memory.
    EXPECT_EQ(captured["buffers"].size(), 11u);
    EXPECT_EQ(captured["bindings"].size(), 11u);
    EXPECT_EQ(captured["addresses"].size(), 11u);
    EXPECT_EQ(captured["destroyedBuffers"].size(), 11u);
    EXPECT_EQ(captured["freedMemories"].size(), 11u);
    for (const auto& m : captured["memories"])
        EXPECT_TRUE(m["propertyFlags"].get<uint32_t>() & 0x2) << m;
    const json& device = captured["devices"][0];
    EXPECT_TRUE(device["servedByLayer"].get<bool>());
    EXPECT_TRUE(device["clusterFeatureEnabled"].get<bool>());
    EXPECT_EQ(device["clusterProperties"]["maxTrianglesPerCluster"], 256);
}

TEST_F(ExactnessRun, SubmitRangeOutsideTheSubmissionCapturesNoBuild) {
    runExactness({{"CLASTRACE_SUBMIT_RANGE", "5-"}});
    EXPECT_TRUE(captured["clusterBuilds"].empty());
    EXPECT_TRUE(captured["submissions"].empty());
    EXPECT_EQ(captured["commandBuffers"].size(),
              1u);  // recording happens before the index is known
}

TEST_F(ExactnessRun, CaptureOffStillServesWithoutWriting) {
    runExactness({{"CLASTRACE_CAPTURE", "0"}});
    EXPECT_FALSE(fs::exists(dir / "capture.json"));
    EXPECT_FALSE(expected.empty());  // the application ran its builds to the end
}

TEST_F(ExactnessRun, EachResubmissionIsCapturedWithItsOwnHostWrittenCount) {
    ProcessResult r =
        run(app("resubmit 7"), {{"CLASTRACE_DEBUG_JSON", (dir / "capture.json").string()}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    captured = json::parse(readText(dir / "capture.json"));
    ASSERT_EQ(captured["clusterBuilds"].size(), 7u);
    ASSERT_EQ(captured["submissions"].size(), 7u);
    for (size_t i = 0; i < 7; ++i) {
        const json& build = captured["clusterBuilds"][i];
        EXPECT_EQ(build["submissionIndex"], captured["submissions"][i]["index"]);
        EXPECT_EQ(build["executedCount"], i % 3 + 1) << "submission " << i;
        EXPECT_EQ(ranges(build, "srcInfos").size(), 1u);
        EXPECT_EQ(ranges(build, "srcInfos")[0]["size"], 64 * (i % 3 + 1));
        EXPECT_EQ(ranges(build, "indexBuffer").size(), i % 3 + 1);
    }
}

// The host rewriting the src infos of a submitted build: tests/capture/host_write_watch_test.cpp,
// with the hash watch and the page guard.

TEST_F(ExactnessRun, DispatchRecordsItsPipelineAndBoundStorageBuffers) {
    ProcessResult r = run(app("dispatch " + (dir / "expected.json").string()),
                          {{"CLASTRACE_DEBUG_JSON", (dir / "capture.json").string()}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    expected = json::parse(readText(dir / "expected.json"));
    captured = json::parse(readText(dir / "capture.json"));
    std::vector<json> dispatches;
    for (const auto& c : captured["commandBuffers"][0]["commands"])
        if (c["kind"] == "Dispatch") dispatches.push_back(c);
    ASSERT_EQ(dispatches.size(), 2u);
    EXPECT_EQ(dispatches[0]["groups"], json::array({2, 3, 4}));
    EXPECT_EQ(dispatches[0]["pipeline"], expected["pipeline"]);
    for (size_t i = 0; i < 2; ++i) {
        const json& buffers = dispatches[i]["storageBuffers"];
        ASSERT_EQ(buffers.size(), 2u);
        EXPECT_EQ(buffers[0]["binding"], 0);
        EXPECT_EQ(buffers[0]["buffer"], expected["a"]["buffer"]);
        EXPECT_EQ(buffers[0]["offset"], 256);
        EXPECT_EQ(buffers[0]["range"], 512);
        EXPECT_EQ(buffers[0]["address"], expected["a"]["address"].get<uint64_t>() + 256);
        EXPECT_EQ(buffers[1]["binding"], 1);
        EXPECT_EQ(buffers[1]["type"], 9);  // VK_DESCRIPTOR_TYPE_STORAGE_BUFFER_DYNAMIC
        EXPECT_EQ(buffers[1]["buffer"], expected["b"]["buffer"]);
    }
    EXPECT_EQ(dispatches[0]["storageBuffers"][1]["offset"],
              256);  // the dynamic offset of each bind
    EXPECT_EQ(dispatches[1]["storageBuffers"][1]["offset"], 1024);
}

// The same run written as a .clt trace and read back with the trace reader.
TEST_F(ExactnessRun, TraceHoldsTheBuildsWithTheirSnapshots) {
    const fs::path trace = dir / "capture.clt";
    ProcessResult r = run(app("exactness " + (dir / "expected.json").string()),
                          {{"CLASTRACE_OUTPUT", trace.string()}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    expected = json::parse(readText(dir / "expected.json"));
    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
    ASSERT_TRUE(reader) << error.message;
    EXPECT_TRUE(reader->has_index());  // finished when the loader unloaded the layer
    ASSERT_TRUE(reader->header() && reader->header()->device());
    EXPECT_NE(reader->header()->device()->name()->str().find("llvmpipe"), std::string::npos);
    EXPECT_EQ(reader->header()->device()->cluster_properties()->max_triangles_per_cluster(), 256u);
    EXPECT_EQ(reader->header()->capture()->application_name()->str(), "cluster_capture_app");

    // Every snapshot (address -> bytes) of the two builds, in record order.
    std::vector<std::vector<std::pair<uint64_t, std::string>>> builds;
    std::vector<std::string> kinds;
    clastrace::traces::RecordView view;
    std::vector<std::pair<uint64_t, uint64_t>> snapshots;  // (address, hash) of the current build
    std::vector<std::vector<std::pair<uint64_t, uint64_t>>> pendingBuilds;
    uint64_t submissions = 0;
    while (reader->next(&view)) {
        if (view.kind == clastrace::fbs::RecordBody::QueueSubmit) ++submissions;
        if (view.kind != clastrace::fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect)
            continue;
        const auto* build = view.record->body_as_CmdBuildClusterAccelerationStructureIndirect();
        std::vector<std::pair<uint64_t, uint64_t>> list;
        for (const auto* s : *build->inputs()) list.emplace_back(s->address(), s->hash());
        pendingBuilds.push_back(list);
    }
    EXPECT_TRUE(reader->damage().empty()) << reader->damage()[0].message;
    EXPECT_EQ(submissions, 1u);
    ASSERT_EQ(pendingBuilds.size(), 2u);
    auto bytesAt = [&](size_t build, uint64_t address) {
        for (const auto& [a, hash] : pendingBuilds[build])
            if (a == address) {
                std::vector<uint8_t> bytes;
                auto e = reader->read_contents(hash, &bytes);
                EXPECT_FALSE(e) << e.message;
                std::string hex;
                for (uint8_t b : bytes)
                    hex += "0123456789abcdef"[b >> 4], hex += "0123456789abcdef"[b & 15];
                return hex;
            }
        return std::string("<no snapshot>");
    };
    const json& want = expected["clusterBuild"];
    EXPECT_EQ(bytesAt(0, want["srcInfosCount"]["address"]), want["srcInfosCount"]["bytes"]);
    for (const char* role :
         {"srcInfos", "indexBuffer", "vertexBuffer", "geometryIndexAndFlagsBuffer"})
        for (const auto& range : want[role])
            EXPECT_EQ(bytesAt(0, range["address"]), range["bytes"]) << role;
    const json& blas = expected["bottomLevelBuild"];
    EXPECT_EQ(bytesAt(1, blas["clusterReferences"][0]["address"]),
              blas["clusterReferences"][0]["bytes"]);
}

// ---- The launcher -----------------------------------------------------------------------

TEST_F(LayerProcess, LauncherRunsTheApplicationUnderTheLayer) {
    const fs::path trace = dir / "launched.clt";
    // No VK_ADD_LAYER_PATH/VK_INSTANCE_LAYERS from the test: the launcher sets them.
    ProcessResult r = run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " capture -o " +
                              trace.string() + " --layer-path " + CLASTRACE_LAYER_MANIFEST_DIR +
                              " -- " + app("exactness " + (dir / "expected.json").string()),
                          {}, false);
    ASSERT_EQ(r.exitCode, 0) << r.err;
    EXPECT_NE(r.err.find("clastrace capture: wrote '" + trace.string() + "'"), std::string::npos)
        << r.err;
    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
    ASSERT_TRUE(reader) << error.message;
    size_t builds = 0;
    clastrace::traces::RecordView view;
    while (reader->next(&view))
        if (view.kind == clastrace::fbs::RecordBody::CmdBuildClusterAccelerationStructureIndirect)
            ++builds;
    EXPECT_EQ(builds, 2u);
}

TEST_F(LayerProcess, LauncherRefusesAnUnwritableOutputAndPassesExitCodes) {
    ProcessResult r =
        run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " capture -o /nonexistent-dir/x.clt -- true",
            {}, false);
    EXPECT_EQ(r.exitCode, 2);
    EXPECT_NE(r.err.find("cannot write '/nonexistent-dir/x.clt'"), std::string::npos) << r.err;
    r = run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " capture -o " + (dir / "x.clt").string() +
                " -- sh -c 'exit 7'",
            {}, false);
    EXPECT_EQ(r.exitCode, 7) << r.err;
    EXPECT_NE(r.err.find("was not written"), std::string::npos)
        << r.err;  // sh makes no Vulkan device
}

TEST_F(LayerProcess, LauncherPassesItsSettingsToTheLayerEnvironment) {
    const fs::path trace = dir / "settings.clt";
    ProcessResult r =
        run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " capture -o " + trace.string() +
                " --ray-check 64 --zstd-level 7 --serve 0 -- sh -c 'env | grep ^CLASTRACE_ | sort'",
            {}, false);
    EXPECT_NE(r.out.find("CLASTRACE_RAY_CHECK=64\n"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("CLASTRACE_ZSTD_LEVEL=7\n"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("CLASTRACE_SERVE=0\n"), std::string::npos) << r.out;
    r = run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " capture -o " + trace.string() +
                " -- sh -c 'env'",
            {}, false);
    EXPECT_EQ(r.out.find("CLASTRACE_RAY_CHECK="), std::string::npos) << "off unless asked for";
    r = run(std::string(CLASTRACE_CAPTURE_LAUNCHER) + " capture -o " + trace.string() +
                " --ray-check 2000000 -- true",
            {}, false);
    EXPECT_EQ(r.exitCode, 2) << r.err;
}

// The injected barrier/event sequence under the Khronos validation layer with synchronization
// validation, placed beneath the capture layer so it sees what the driver sees.
TEST_F(LayerProcess, InjectedPausesPassSynchronizationValidation) {
    if (!fs::exists(kValidationLayerManifest))
        GTEST_SKIP() << "vulkan-validationlayers is not installed";
    std::map<std::string, std::string> env = synchronizationValidation();
    // the engine's own findings name VUIDs too: only the validation layer's messages count here
    env["CLASTRACE_LOG"] = "quiet";
    env["CLASTRACE_DEBUG_JSON"] = (dir / "capture.json").string();
    for (const std::string& mode :
         {"exactness " + (dir / "expected.json").string(), std::string("resubmit 4"),
          "dispatch " + (dir / "dispatch.json").string(),
          "serve " + (dir / "serve.json").string()}) {
        ProcessResult r = run(app(mode), env, false);
        ASSERT_EQ(r.exitCode, 0) << mode << ": " << r.err;
        const std::string all = r.out + r.err;
        EXPECT_EQ(all.find("VUID-"), std::string::npos) << mode << ": " << all;
        EXPECT_EQ(all.find("SYNC-"), std::string::npos) << mode << ": " << all;
        EXPECT_EQ(count(all, "Validation Error"), 0u) << mode << ": " << all;
        ASSERT_TRUE(
            fs::exists(dir / "capture.json"));  // the layer did run above the validation layer
        EXPECT_FALSE(json::parse(readText(dir / "capture.json"))["commandBuffers"].empty());
    }
}

// ---- Failure handling --------------------------------------------------------------------

TEST_F(LayerProcess, UnwritableOutputGivesOneMessageAndTheApplicationRuns) {
    for (const char* variable : {"CLASTRACE_DEBUG_JSON", "CLASTRACE_OUTPUT"}) {
        ProcessResult r = run(app("exactness " + (dir / "expected.json").string()),
                              {{variable, "/nonexistent-dir/capture.out"}});
        EXPECT_EQ(r.exitCode, 0) << variable << ": " << r.err;
        EXPECT_EQ(count(r.err,
                        "clastrace: capture disabled: cannot write '/nonexistent-dir/capture.out'"),
                  1u)
            << variable << ": " << r.err;
        EXPECT_TRUE(fs::exists(dir / "expected.json"));
        fs::remove(dir / "expected.json");
    }
}

TEST_F(LayerProcess, BadSettingIsReportedOnceByName) {
    ProcessResult r =
        run(app("limits " + (dir / "limits.json").string()), {{"CLASTRACE_ZSTD_LEVEL", "99"}});
    EXPECT_EQ(r.exitCode, 0) << r.err;
    EXPECT_EQ(count(r.err, "CLASTRACE_ZSTD_LEVEL='99'"), 1u) << r.err;
}

}  // namespace
