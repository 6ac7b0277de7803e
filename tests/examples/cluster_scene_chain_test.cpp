// SPDX-License-Identifier: Apache-2.0
// The sample application end to end on lavapipe: examples/cluster_scene under the capture
// layer (capture + serving) -> trace -> replay. The replay must reproduce every output byte
// the application read back and find no hazard; each barrier the application leaves out
// must give exactly the hazards that barrier prevents; two threads recording two command
// buffers must lose no command.
#include "layer_launch_test.h"

#include <clastrace/replay/hazard_report.h>
#include <clastrace/vk_cluster_abi.h>
#include <clastrace/replay/replay_report.h>
#include <clastrace/replay/replayer.h>
#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <set>
#include <sstream>
#include <tuple>

namespace {

namespace fs = std::filesystem;
using clastrace::fbs::RecordBody;
using nlohmann::json;

using namespace clastrace::layer_launch;

// A subset of the mesh keeps each skipped-barrier run well under a second on lavapipe.
const char* kSubset = "--max-clusters 6";

// FNV-1a 64, as the application digests the objects it reads back.
uint64_t fnv1a64(const std::vector<uint8_t>& bytes, size_t begin, size_t size) {
    uint64_t h = 0xcbf29ce484222325ull;
    for (size_t i = begin; i < begin + size; ++i) h = (h ^ bytes[i]) * 0x100000001b3ull;
    return h;
}

std::string digestText(uint64_t v) {
    char text[24];
    std::snprintf(text, sizeof text, "0x%016llx", (unsigned long long)v);
    return text;
}

// One command of the trace, in the order of its command buffer.
struct TracedCommand {
    std::string kind;  // "copy", "barrier", "build", "other"
    uint32_t opType = 0, opMode = 0;
    std::vector<std::pair<uint64_t, std::vector<uint8_t>>> outputs;  // address, bytes
    int moveType = -1;  // moves: VkClusterAccelerationStructureTypeNV of what moved
    // Traceable BLASes: where the driver built its own BLAS, which the application reads back.
    std::vector<std::pair<uint64_t, uint64_t>> driverBvh;  // address, size
};

struct TracedScene {
    std::map<uint64_t, std::vector<TracedCommand>> commandBuffers;  // handle -> commands
    uint64_t submissions = 0, outputSnapshots = 0;
    std::string driver;
};

class ClusterSceneChain : public LayerLaunchTest {
public:
    ClusterSceneChain() : LayerLaunchTest("clastrace_scene") {}
    using LayerLaunchTest::run;

    static std::string scene(const std::string& args) {
        return std::string(CLUSTER_SCENE_APP) + " " + args;
    }

    // The application under the layer, writing `trace`; returns its --json output.
    json captureScene(const fs::path& trace, const std::string& args) {
        ProcessResult r = run(scene(args + " --json"), {{"CLASTRACE_OUTPUT", trace.string()}});
        EXPECT_EQ(r.exitCode, 0) << r.err;
        EXPECT_EQ(r.err, "");  // no layer finding: every build is valid
        if (r.exitCode != 0) return json();
        return json::parse(r.out);
    }

    static TracedScene readTrace(const fs::path& trace) {
        TracedScene t;
        clastrace::traces::TraceError error;
        auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
        EXPECT_TRUE(reader) << error.message;
        if (!reader) return t;
        EXPECT_TRUE(reader->has_index());
        if (reader->header() && reader->header()->device() &&
            reader->header()->device()->driver_name())
            t.driver = reader->header()->device()->driver_name()->str();
        // (command buffer, command index) -> output (address, content hash), read after the records.
        std::vector<std::tuple<uint64_t, size_t, std::vector<std::pair<uint64_t, uint64_t>>>>
            pending;
        clastrace::traces::RecordView view;
        while (reader->next(&view)) {
            const clastrace::fbs::Record* r = view.record;
            switch (view.kind) {
            case RecordBody::QueueSubmit: ++t.submissions; break;
            case RecordBody::CommandBufferBegin:
                t.commandBuffers[r->body_as_CommandBufferBegin()->command_buffer()].clear();
                break;
            case RecordBody::CmdCopyBuffer:
                t.commandBuffers[r->body_as_CmdCopyBuffer()->command_buffer()].push_back(
                    TracedCommand{"copy", 0, 0, {}, -1, {}});
                break;
            case RecordBody::CmdPipelineBarrier:
                t.commandBuffers[r->body_as_CmdPipelineBarrier()->command_buffer()].push_back(
                    TracedCommand{"barrier", 0, 0, {}, -1, {}});
                break;
            case RecordBody::CmdBuildClusterAccelerationStructureIndirect: {
                const auto* b = r->body_as_CmdBuildClusterAccelerationStructureIndirect();
                TracedCommand c{"build",
                                uint32_t(b->input()->op_type()),
                                uint32_t(b->input()->op_mode()),
                                {},
                                -1,
                                {}};
                if (const auto* move = b->input()->op_input_as_MoveObjectsInput())
                    c.moveType = int(move->type());
                if (b->driver_bvh())
                    for (const auto* d : *b->driver_bvh())
                        c.driverBvh.emplace_back(d->address(), d->size());
                auto& list = t.commandBuffers[b->command_buffer()];
                list.push_back(c);
                std::vector<std::pair<uint64_t, uint64_t>> outputs;
                if (b->outputs())
                    for (const auto* s : *b->outputs())
                        outputs.emplace_back(s->address(), s->hash());
                pending.emplace_back(b->command_buffer(), list.size() - 1, outputs);
                break;
            }
            case RecordBody::CmdFillBuffer:
            case RecordBody::CmdUpdateBuffer:
            case RecordBody::CmdSetEvent:
            case RecordBody::CmdWaitEvents:
            case RecordBody::CmdResetEvent:
            case RecordBody::CmdDispatch: {
                // Not recorded by the application: the layer's own pause commands must not show.
                ADD_FAILURE() << "unexpected command record kind " << int(view.kind);
                break;
            }
            default: break;
            }
        }
        EXPECT_TRUE(reader->damage().empty());
        for (auto& [commandBuffer, index, outputs] : pending)
            for (const auto& [address, hash] : outputs) {
                TracedCommand* command = &t.commandBuffers[commandBuffer][index];
                std::vector<uint8_t> bytes;
                auto e = reader->read_contents(hash, &bytes);
                EXPECT_FALSE(e) << e.message;
                command->outputs.emplace_back(address, std::move(bytes));
                ++t.outputSnapshots;
            }
        return t;
    }

    static clastrace::replay::ReplayReport replay(const fs::path& trace) {
        clastrace::traces::TraceError error;
        auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
        EXPECT_TRUE(reader) << error.message;
        if (!reader) return {};
        return clastrace::replay::replay_trace(*reader, trace.string());
    }
};

std::string describe(const clastrace::replay::ReplayReport& report) {
    std::string text;
    for (const auto& f : report.findings) text += f.format() + "\n";
    for (const auto& h : report.hazards) text += h.format() + "\n";
    for (const auto& d : report.trace_damage) text += d + "\n";
    return text;
}

// The application's view (json) against the trace's: same commands in the same order.
void expectSameCommands(const json& app, const std::vector<TracedCommand>& traced) {
    std::vector<std::string> appKinds, tracedKinds;
    for (const auto& c : app["commands"]) {
        const std::string s = c;
        appKinds.push_back(s.substr(0, s.find(':')));
    }
    for (const auto& c : traced) tracedKinds.push_back(c.kind);
    EXPECT_EQ(tracedKinds, appKinds);
    size_t copies = 0, barriers = 0, builds = 0;
    for (const auto& k : tracedKinds)
        copies += k == "copy", barriers += k == "barrier", builds += k == "build";
    EXPECT_EQ(copies, app["counts"]["copies"].get<size_t>());
    EXPECT_EQ(barriers, app["counts"]["barriers"].get<size_t>());
    EXPECT_EQ(builds, app["counts"]["builds"].get<size_t>());
}

// Every array and object the application read back is a captured output of its build.
void expectCapturedOutputsAreWhatTheAppSaw(const json& app,
                                           const std::vector<TracedCommand>& traced) {
    std::vector<const TracedCommand*> builds;
    for (const auto& c : traced)
        if (c.kind == "build") builds.push_back(&c);
    ASSERT_EQ(builds.size(), app["builds"].size());
    for (size_t i = 0; i < builds.size(); ++i) {
        const json& b = app["builds"][i];
        const TracedCommand& t = *builds[i];
        const std::string label = b["label"];
        EXPECT_EQ(t.opType, b["opType"].get<uint32_t>()) << label;
        EXPECT_EQ(t.opMode, b["opMode"].get<uint32_t>()) << label;
        auto snapshotAt = [&](uint64_t address,
                              uint64_t size) -> std::optional<std::vector<uint8_t>> {
            for (const auto& [at, bytes] : t.outputs)
                if (address >= at && address - at + size <= bytes.size())
                    return std::vector<uint8_t>(bytes.begin() + (address - at),
                                                bytes.begin() + (address - at + size));
            return std::nullopt;
        };
        const uint32_t ops = b["ops"];
        auto sizes = snapshotAt(b["dstSizesArray"], 4ull * ops);
        ASSERT_TRUE(sizes) << label << ": no captured dstSizesArray";
        EXPECT_EQ(hexOf(*sizes), b["sizesBytes"].get<std::string>()) << label;
        if (b["addresses"].empty()) continue;  // compute-sizes mode writes sizes only
        auto addresses = snapshotAt(b["dstAddressesArray"], 8ull * ops);
        ASSERT_TRUE(addresses) << label << ": no captured dstAddressesArray";
        EXPECT_EQ(hexOf(*addresses), b["addressesBytes"].get<std::string>()) << label;
        for (uint32_t op = 0; op < ops; ++op) {
            const uint64_t at = b["addresses"][op], size = b["sizes"][op];
            // A traceable BLAS: the application read the driver's BVH at the start of the
            // object, the trace keeps the engine's object (the replay test compares that one).
            const bool driverBuilt =
                std::any_of(t.driverBvh.begin(), t.driverBvh.end(), [&](const auto& d) {
                    return d.first < at + size && at < d.first + d.second;
                });
            if (driverBuilt) continue;
            auto object = snapshotAt(at, size);
            ASSERT_TRUE(object) << label << " op " << op << ": object bytes not captured";
            EXPECT_EQ(digestText(fnv1a64(*object, 0, object->size())),
                      b["objectDigests"][op].get<std::string>())
                << label << " op " << op;
        }
    }
}

// The default mesh (a subset and whole), and other OBJ files of assimp-testmodels down to
// a single cluster.
class CleanScene : public ClusterSceneChain,
                   public ::testing::WithParamInterface<std::pair<std::string, int>> {};

TEST_P(CleanScene, ReplayReproducesEveryOutputAndFindsNoHazard) {
    const auto& [args, clusters] = GetParam();
    const fs::path trace = dir / "scene.clt";
    const json app = captureScene(trace, args);
    ASSERT_FALSE(app.is_null());
    ASSERT_EQ(app["scenes"].size(), 1u);
    const json& scene = app["scenes"][0];
    EXPECT_EQ(app["clusters"], clusters);
    if (args.find("--max-clusters") == std::string::npos)
        EXPECT_EQ(app["clusterTriangles"], app["triangles"]);
    else
        EXPECT_LT(app["clusterTriangles"], app["triangles"]);  // a subset

    const TracedScene traced = readTrace(trace);
    EXPECT_EQ(traced.driver, "clastrace engine");  // served: its outputs are the engine's bytes
    EXPECT_EQ(traced.submissions, 1u);
    ASSERT_EQ(traced.commandBuffers.count(scene["commandBuffer"]), 1u);
    const auto& commands = traced.commandBuffers.at(scene["commandBuffer"]);
    expectSameCommands(scene, commands);
    expectCapturedOutputsAreWhatTheAppSaw(scene, commands);

    // Each op type, and compute-sizes mode, traced at least once.
    std::set<uint32_t> opTypes;
    bool computeSizes = false;
    for (const auto& c : commands)
        if (c.kind == "build") opTypes.insert(c.opType), computeSizes |= c.opMode == 2;
    EXPECT_EQ(opTypes, (std::set<uint32_t>{0, 1, 2, 3, 4, 5}));
    EXPECT_TRUE(computeSizes);
    std::set<int> moved;  // clusters and templates
    for (const auto& c : commands)
        if (c.kind == "build" && c.opType == 0) moved.insert(c.moveType);
    EXPECT_EQ(moved,
              (std::set<int>{VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV,
                             VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_TEMPLATE_NV}));

    const clastrace::replay::ReplayReport report = replay(trace);
    EXPECT_TRUE(report.engine_trace);
    EXPECT_TRUE(report.clean()) << describe(report);
    EXPECT_TRUE(report.not_replayed.empty());
    EXPECT_EQ(report.counts.cluster_commands, 8u);
    EXPECT_EQ(report.counts.copies, scene["counts"]["copies"].get<uint64_t>());
    EXPECT_EQ(report.counts.barriers, scene["counts"]["barriers"].get<uint64_t>());
    // Every captured output snapshot was compared with the engine's bytes, and all were equal
    // (a difference is a CLASTRACE-replay-output-differs finding, and there is none).
    EXPECT_EQ(report.counts.outputs_compared, traced.outputSnapshots);
    EXPECT_GT(report.counts.output_bytes_compared, 0u);
    // Per op type and mode: every op's size compared and equal.
    std::map<std::pair<uint32_t, bool>, uint32_t> comparedOps;  // (op type, compute-sizes) -> ops
    ASSERT_EQ(report.sizes.size(), 8u);
    const std::vector<const TracedCommand*> builds = [&] {
        std::vector<const TracedCommand*> b;
        for (const auto& c : commands)
            if (c.kind == "build") b.push_back(&c);
        return b;
    }();
    for (size_t i = 0; i < report.sizes.size(); ++i) {
        const auto& s = report.sizes[i];
        EXPECT_EQ(s.ops, s.ops_compared) << i;
        EXPECT_EQ(s.sizes_equal, s.ops_compared) << i;
        EXPECT_EQ(s.captured_bytes, s.engine_bytes) << i;
        comparedOps[{s.op_type, builds[i]->opMode == 2}] += s.sizes_equal;
    }
    for (uint32_t type = 0; type < 6; ++type)
        EXPECT_GT((comparedOps[{type, false}]), 0u) << "op type " << type;
    EXPECT_GT((comparedOps[{2u, true}]), 0u) << "compute-sizes";

    // The command-line replay agrees.
    ProcessResult cli =
        run(std::string(CLASTRACE_CLI) + " replay --json " + trace.string(), {}, false);
    EXPECT_EQ(cli.exitCode, 0) << cli.out << cli.err;
    const json replayed = json::parse(cli.out);
    EXPECT_TRUE(replayed["clean"].get<bool>());
    EXPECT_EQ(replayed["counts"]["outputs_compared"], traced.outputSnapshots);

    // `clastrace info` says the extension was served, not the driver's.
    ProcessResult info =
        run(std::string(CLASTRACE_CLI) + " info --json " + trace.string(), {}, false);
    EXPECT_EQ(info.exitCode, 0) << info.err;
    const json features = json::parse(info.out)["header"]["device"]["cluster_features"];
    EXPECT_EQ(features["served"], true);
    EXPECT_EQ(features["enabled"], true);
    ProcessResult infoText = run(std::string(CLASTRACE_CLI) + " info " + trace.string(), {}, false);
    EXPECT_NE(infoText.out.find(
                  "supported yes, enabled yes (served: the capture layer advertised it"),
              std::string::npos)
        << infoText.out;

    // And the analyzer (the quick start's last step) reads the same commands and ops.
    ProcessResult analyzed =
        run(std::string(CLASTRACE_CLI) + " analyze --json " + trace.string(), {}, false);
    EXPECT_EQ(analyzed.exitCode, 0) << analyzed.err;
    const json analysis = json::parse(analyzed.out);
    uint64_t ops = 0;
    for (const auto& b : scene["builds"]) ops += b["ops"].get<uint64_t>();
    // totals.commands counts every submitted command (copies and barriers too, schema 2).
    uint64_t listedBuilds = 0;
    for (const auto& c : analysis["commands"]["listed"])
        listedBuilds += c["name"] == "vkCmdBuildClusterAccelerationStructureIndirectNV";
    EXPECT_EQ(listedBuilds, 8u);
    EXPECT_GT(analysis["totals"]["commands"].get<uint64_t>(), 8u);
    EXPECT_EQ(analysis["totals"]["ops"], ops);
    EXPECT_EQ(analysis["hazards"]["total"], 0);
    // The sample instantiates templates it moved first: the analyzer still counts their
    // triangles (from the instantiated objects), equal to the templates'.
    uint64_t template_triangles = 0, instantiated_triangles = 0;
    for (const auto& t : analysis["sizes"]["by_op_type"]) {
        if (t["op_type"] == "build_triangle_cluster_template")
            template_triangles = t["triangles"].get<uint64_t>();
        if (t["op_type"] == "instantiate_triangle_cluster")
            instantiated_triangles = t["triangles"].get<uint64_t>();
    }
    EXPECT_GT(template_triangles, 0u);
    EXPECT_EQ(instantiated_triangles, template_triangles);
}

const std::vector<std::pair<std::string, int>> kMeshes = {
    {kSubset, 6},
    {"", 43},  // all of WusonOBJ.obj
    {"/usr/share/assimp/models/OBJ/spider.obj", 14},
    {"/usr/share/assimp/models/OBJ/box.obj", 1},
};
std::string meshName(const ::testing::TestParamInfo<std::pair<std::string, int>>& info) {
    static const char* names[] = {"WusonSubset", "Wuson", "Spider", "Box"};
    return names[info.index];
}
INSTANTIATE_TEST_SUITE_P(Meshes, CleanScene, ::testing::ValuesIn(kMeshes), meshName);

// The sample's own Vulkan use (copies, barriers, fences, two threads) under the Khronos
// validation layer with synchronization validation, beneath the capture layer.
TEST_F(ClusterSceneChain, PassesSynchronizationValidation) {
    if (!fs::exists(kValidationLayerManifest))
        GTEST_SKIP() << "vulkan-validationlayers is not installed";
    std::map<std::string, std::string> env = synchronizationValidation();
    for (const std::string& args : {std::string(kSubset), std::string(kSubset) + " --threads 2"}) {
        const fs::path trace = dir / "validated.clt";
        env["CLASTRACE_OUTPUT"] = trace.string();
        ProcessResult r = run(scene(args), env, false);
        ASSERT_EQ(r.exitCode, 0) << args << ": " << r.err;
        const std::string all = r.out + r.err;
        EXPECT_EQ(all.find("VUID-"), std::string::npos) << args << ": " << all;
        EXPECT_EQ(all.find("SYNC-"), std::string::npos) << args << ": " << all;
        EXPECT_EQ(all.find("Validation"), std::string::npos) << args << ": " << all;
        EXPECT_NE(r.out.find("8 builds"), std::string::npos) << r.out;
        EXPECT_TRUE(fs::exists(trace));  // the capture layer did run above the validation layer
        fs::remove(trace);
    }
}

// ---- GPU timestamps ------------------------------------------------------------------

// The layer's timestamps of one command buffer, in the order of its commands.
struct TracedTimeline {
    std::string
        order;  // per command: 'T' timestamp, 'B' cluster build, 'c' copy, 'b' barrier, 'o' other
    std::vector<const clastrace::fbs::GpuTimestamp*> timestamps;
    float periodNs = 0;
};

// Reads one trace and hands each command buffer's timeline to `check` (the records stay alive
// while it runs).
void forEachTimeline(const fs::path& trace,
                     const std::function<void(uint64_t, const TracedTimeline&)>& check) {
    clastrace::traces::TraceError error;
    auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
    ASSERT_TRUE(reader) << error.message;
    ASSERT_TRUE(reader->header() && reader->header()->device());
    std::vector<clastrace::traces::RecordView> views;
    std::map<uint64_t, TracedTimeline> timelines;
    clastrace::traces::RecordView view;
    while (reader->next(&view)) {
        const clastrace::fbs::Record* r = view.record;
        uint64_t cb = 0;
        char kind = 'o';
        switch (view.kind) {
        case RecordBody::CommandBufferBegin:
            timelines[r->body_as_CommandBufferBegin()->command_buffer()] = {};
            continue;
        case RecordBody::GpuTimestamp: {
            const auto* t = r->body_as_GpuTimestamp();
            cb = t->command_buffer();
            timelines[cb].timestamps.push_back(t);
            kind = 'T';
            break;
        }
        case RecordBody::CmdBuildClusterAccelerationStructureIndirect:
            cb = r->body_as_CmdBuildClusterAccelerationStructureIndirect()->command_buffer(),
            kind = 'B';
            break;
        case RecordBody::CmdCopyBuffer:
            cb = r->body_as_CmdCopyBuffer()->command_buffer(), kind = 'c';
            break;
        case RecordBody::CmdPipelineBarrier:
            cb = r->body_as_CmdPipelineBarrier()->command_buffer(), kind = 'b';
            break;
        default: continue;
        }
        timelines[cb].order += kind;
    }
    for (auto& [cb, timeline] : timelines) {
        timeline.periodNs = reader->header()->device()->timestamp_period_ns();
        check(cb, timeline);
    }
}

// Each captured build between a pair of the layer's timestamps, read back valid and in order;
// the analyzer turns each pair into the build's gpu_ns. CLASTRACE_TIMESTAMPS=0: none at all.
TEST_F(ClusterSceneChain, TimestampsAroundEachCapturedBuildGiveItsGpuTime) {
    for (const std::string& args : {std::string(kSubset), std::string(kSubset) + " --threads 2"}) {
        const fs::path trace = dir / "timed.clt";
        const json app = captureScene(trace, args);
        ASSERT_FALSE(app.is_null()) << args;
        size_t builds = 0, timelines = 0, spans = 0;
        forEachTimeline(trace, [&](uint64_t cb, const TracedTimeline& t) {
            ++timelines;
            if (!t.timestamps.empty())
                spans += t.timestamps.size() - 1;  // the analyzer spans each neighbouring pair
            EXPECT_GT(t.periodNs, 0.0f);           // lavapipe's timestampPeriod reaches the header
            const size_t b = size_t(std::count(t.order.begin(), t.order.end(), 'B'));
            builds += b;
            ASSERT_EQ(t.timestamps.size(), 2 * b) << std::hex << cb << " " << t.order;
            // Every build sits alone between its pair: T B T.
            for (size_t i = 0; i < t.order.size(); ++i)
                if (t.order[i] == 'B') {
                    ASSERT_TRUE(i > 0 && i + 1 < t.order.size()) << t.order;
                    EXPECT_EQ(t.order[i - 1], 'T') << t.order;
                    EXPECT_EQ(t.order[i + 1], 'T') << t.order;
                }
            std::set<uint32_t> queries;
            for (size_t i = 0; i + 1 < t.timestamps.size(); i += 2) {
                const auto* start = t.timestamps[i];
                const auto* end = t.timestamps[i + 1];
                EXPECT_TRUE(start->ticks_valid() && end->ticks_valid()) << i;
                EXPECT_EQ(start->stage_mask(), uint64_t(VK_PIPELINE_STAGE_ALL_COMMANDS_BIT));
                EXPECT_EQ(end->stage_mask(), uint64_t(VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT));
                EXPECT_EQ(start->query_pool(), end->query_pool());
                EXPECT_NE(start->query_pool(), 0u);
                // Served, the span covers the pause where the engine ran the build: never empty.
                EXPECT_GT(end->ticks(), start->ticks()) << i;
                if (i >= 2) {
                    EXPECT_GE(start->ticks(), t.timestamps[i - 1]->ticks()) << i;  // in queue order
                }
                queries.insert(start->query()), queries.insert(end->query());
            }
            EXPECT_EQ(queries.size(), t.timestamps.size());
        });
        EXPECT_EQ(builds, 8u * (args.find("--threads 2") != std::string::npos ? 2 : 1)) << args;
        EXPECT_GE(timelines, 1u);

        ProcessResult analyzed =
            run(std::string(CLASTRACE_CLI) + " analyze --json " + trace.string(), {}, false);
        ASSERT_EQ(analyzed.exitCode, 0) << analyzed.err;
        const json analysis = json::parse(analyzed.out);
        EXPECT_TRUE(analysis["timing"]["gpu_timing_present"].get<bool>());
        EXPECT_EQ(analysis["timing"]["gpu_spans"]["total"].get<uint64_t>(), spans);
        EXPECT_GT(analysis["timing"]["gpu_spans"]["gpu_ns"].get<double>(), 0.0);
        size_t timed = 0;
        for (const auto& c : analysis["commands"]["listed"])
            if (c["name"] == "vkCmdBuildClusterAccelerationStructureIndirectNV") {
                ASSERT_TRUE(c["gpu_ns"].is_number()) << c.dump();
                EXPECT_GT(c["gpu_ns"].get<double>(), 0.0) << c.dump();
                ++timed;
            }
        EXPECT_EQ(timed, builds);
        fs::remove(trace);
    }

    // Off: no query in the trace, and the analyzer has no GPU time.
    const fs::path trace = dir / "untimed.clt";
    ProcessResult r = run(scene(std::string(kSubset)),
                          {{"CLASTRACE_OUTPUT", trace.string()}, {"CLASTRACE_TIMESTAMPS", "0"}});
    ASSERT_EQ(r.exitCode, 0) << r.err;
    size_t builds = 0;
    forEachTimeline(trace, [&](uint64_t, const TracedTimeline& t) {
        EXPECT_TRUE(t.timestamps.empty()) << t.order;
        builds += size_t(std::count(t.order.begin(), t.order.end(), 'B'));
    });
    EXPECT_EQ(builds, 8u);
    ProcessResult analyzed =
        run(std::string(CLASTRACE_CLI) + " analyze --json " + trace.string(), {}, false);
    ASSERT_EQ(analyzed.exitCode, 0) << analyzed.err;
    EXPECT_FALSE(json::parse(analyzed.out)["timing"]["gpu_timing_present"].get<bool>());
}

// ---- Skipped barriers ---------------------------------------------------------------

// What leaving out each barrier of examples/cluster_scene must give, and nothing else:
// (hazard class, earlier command, later command), commands named as the app names them.
using Expected = std::set<std::tuple<std::string, std::string, std::string>>;
const std::map<std::string, Expected>& expectedHazards() {
    static const std::map<std::string, Expected> table = {
        // Both builds read the copied cluster infos; the barrier between them orders builds only.
        {"copy-to-sizes",
         {{"READ-AFTER-WRITE", "copy:cluster-infos", "build:cluster-sizes"},
          {"READ-AFTER-WRITE", "copy:cluster-infos", "build:clusters"}}},
        {"sizes-to-clusters", {{"WRITE-AFTER-WRITE", "build:cluster-sizes", "build:clusters"}}},
        // The template move's srcInfosCount is the copied template count too.
        {"copy-to-templates",
         {{"READ-AFTER-WRITE", "copy:template-infos", "build:templates"},
          {"READ-AFTER-WRITE", "copy:template-infos", "build:template-move"}}},
        {"clusters-to-templates", {{"WRITE-AFTER-WRITE", "build:clusters", "build:templates"}}},
        {"templates-to-template-move",
         {{"READ-AFTER-WRITE", "build:templates", "build:template-move"},
          {"WRITE-AFTER-WRITE", "build:templates", "build:template-move"}}},
        {"template-move-to-address-copy",
         {{"READ-AFTER-WRITE", "build:template-move", "copy:template-addresses"}}},
        {"copy-to-instantiate",
         {{"READ-AFTER-WRITE", "copy:instance-infos", "build:instantiate"},
          {"READ-AFTER-WRITE", "copy:template-addresses", "build:instantiate"}}},
        // The moved templates are ordered before the instantiation by the dependency chain
        // template-move-to-address-copy (build -> transfer) + copy-to-instantiate (transfer ->
        // build): only the scratch reuse is left unordered.
        {"template-move-to-instantiate",
         {{"WRITE-AFTER-WRITE", "build:template-move", "build:instantiate"}}},
        {"instantiate-to-indices",
         {{"WRITE-AFTER-WRITE", "build:instantiate", "build:template-indices"}}},
        {"indices-to-move", {{"WRITE-AFTER-WRITE", "build:template-indices", "build:move"}}},
        {"copy-to-blas", {{"READ-AFTER-WRITE", "copy:blas-infos", "build:blas"}}},
        {"move-to-blas",
         {{"READ-AFTER-WRITE", "build:move", "build:blas"},
          {"WRITE-AFTER-WRITE", "build:move", "build:blas"}}},
    };
    return table;
}

TEST_F(ClusterSceneChain, ListBarriersNamesEveryBarrierTheTestKnows) {
    ProcessResult r = run(scene("--list-barriers"), {}, false);
    ASSERT_EQ(r.exitCode, 0) << r.err;
    std::set<std::string> listed;
    std::istringstream lines(r.out);
    for (std::string line; std::getline(lines, line);)
        listed.insert(line.substr(0, line.find(' ')));
    std::set<std::string> known;
    for (const auto& [name, _] : expectedHazards()) known.insert(name);
    EXPECT_EQ(listed, known);
}

class SkippedBarrier : public ClusterSceneChain,
                       public ::testing::WithParamInterface<std::string> {};

// The sample run under the layer with `skipped` left out; the hazards its replay finds as
// (class, earlier command, later command).
Expected hazardsWithout(ClusterSceneChain& test, const std::vector<std::string>& skipped) {
    const fs::path trace = test.dir / "skipped.clt";
    std::string args = kSubset;
    for (const auto& name : skipped) args += " --skip-barrier " + name;
    const json app = test.captureScene(trace, args);
    if (app.is_null()) return {{"the application failed", "", ""}};
    const json& scene = app["scenes"][0];
    const std::vector<std::string> labels = scene["commands"];
    for (const auto& name : skipped)
        EXPECT_EQ(std::count(labels.begin(), labels.end(), "barrier:" + name), 0) << name;
    EXPECT_EQ(labels.size() + skipped.size(),
              26u);  // 5 copies, 13 barriers (one to the host), 8 builds

    const clastrace::replay::ReplayReport report = test.replay(trace);
    EXPECT_TRUE(report.findings.empty())
        << describe(report);  // serving still wrote the engine's bytes
    EXPECT_TRUE(report.trace_damage.empty());
    // Replay names commands by the application's index (the layer's timestamps don't count).
    auto label = [&](uint64_t index) -> const std::string* {
        return index < labels.size() ? &labels[size_t(index)] : nullptr;
    };
    Expected found;
    for (const auto& h : report.hazards) {
        EXPECT_EQ(h.prior.command.command_buffer_handle, scene["commandBuffer"].get<uint64_t>());
        EXPECT_EQ(h.later.command.command_buffer_handle, scene["commandBuffer"].get<uint64_t>());
        const std::string* prior = label(h.prior.command.command);
        const std::string* later = label(h.later.command.command);
        if (!prior || !later) {
            ADD_FAILURE() << "hazard names a command the application did not record: "
                          << h.format();
            continue;
        }
        found.insert({clastrace::replay::hazard_class_name(h.hazard), *prior, *later});
    }
    return found;
}

TEST_P(SkippedBarrier, GivesExactlyItsHazard) {
    const std::string name = GetParam();
    const Expected found = hazardsWithout(*this, {name});
    EXPECT_EQ(found, expectedHazards().at(name));
}

// --skip-barrier repeats: two barriers left out give both sets, nothing more.
TEST_F(ClusterSceneChain, TwoSkippedBarriersGiveBothHazards) {
    Expected want = expectedHazards().at("sizes-to-clusters");
    want.merge(Expected(expectedHazards().at("copy-to-blas")));
    EXPECT_EQ(hazardsWithout(*this, {"sizes-to-clusters", "copy-to-blas"}), want);
}

INSTANTIATE_TEST_SUITE_P(EachBarrier, SkippedBarrier,
                         ::testing::Values("copy-to-sizes", "sizes-to-clusters",
                                           "copy-to-templates", "clusters-to-templates",
                                           "templates-to-template-move",
                                           "template-move-to-address-copy", "copy-to-instantiate",
                                           "template-move-to-instantiate", "instantiate-to-indices",
                                           "indices-to-move", "copy-to-blas", "move-to-blas"),
                         [](const auto& info) {
                             std::string n = info.param;
                             for (char& c : n)
                                 if (c == '-') c = '_';
                             return n;
                         });

// ---- Multi-threaded recording -------------------------------------------------------

// Two threads record (and submit) one command buffer each, at the same time. Lavapipe has
// one queue, so both go to it under the application's lock; the trace must hold every
// command of both, in each command buffer's order.
TEST_F(ClusterSceneChain, TwoThreadsRecordingLoseNoCommand) {
    const fs::path trace = dir / "threads.clt";
    const json app = captureScene(trace, std::string(kSubset) + " --threads 2");
    ASSERT_FALSE(app.is_null());
    ASSERT_EQ(app["scenes"].size(), 2u);
    EXPECT_GE(app["queues"].get<int>(), 1);
    const TracedScene traced = readTrace(trace);
    EXPECT_EQ(traced.submissions, 2u);
    EXPECT_EQ(traced.commandBuffers.size(), 2u);
    for (const json& scene : app["scenes"]) {
        ASSERT_EQ(traced.commandBuffers.count(scene["commandBuffer"]), 1u);
        const auto& commands = traced.commandBuffers.at(scene["commandBuffer"]);
        expectSameCommands(scene, commands);
        expectCapturedOutputsAreWhatTheAppSaw(scene, commands);
    }
    const clastrace::replay::ReplayReport report = replay(trace);
    EXPECT_TRUE(report.clean()) << describe(report);
    EXPECT_EQ(report.counts.cluster_commands, 16u);
    EXPECT_EQ(report.counts.outputs_compared, traced.outputSnapshots);
}

// ---- The application's own errors -----------------------------------------------------

// --tile N: N copies of the mesh, every triangle of each clustered and built, replayed clean.
TEST_F(ClusterSceneChain, ATiledMeshBuildsEveryCopy) {
    const std::string box = "/usr/share/assimp/models/OBJ/box.obj";
    const json one = captureScene(dir / "one.clt", box);
    const json three = captureScene(dir / "three.clt", box + " --tile 3");
    ASSERT_FALSE(one.is_null());
    ASSERT_FALSE(three.is_null());
    EXPECT_EQ(three["triangles"].get<uint64_t>(), 3 * one["triangles"].get<uint64_t>());
    EXPECT_EQ(three["vertices"].get<uint64_t>(), 3 * one["vertices"].get<uint64_t>());
    EXPECT_EQ(three["clusterTriangles"], three["triangles"]);
    const auto report = replay(dir / "three.clt");
    EXPECT_TRUE(report.findings.empty());
    EXPECT_TRUE(report.hazards.empty());

    const ProcessResult r = run(scene(box + " --tile 65"), {}, false);
    EXPECT_EQ(r.exitCode, 1);  // usage
    EXPECT_NE(r.err.find("--tile"), std::string::npos) << r.err;
}

TEST_F(ClusterSceneChain, ClearErrorsAndExitCodes) {
    ProcessResult r = run(scene("/nonexistent/mesh.obj"), {});
    EXPECT_EQ(r.exitCode, 2);
    EXPECT_NE(r.err.find("/nonexistent/mesh.obj: cannot open"), std::string::npos) << r.err;

    std::ofstream(dir / "bad.obj") << "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n";
    r = run(scene((dir / "bad.obj").string()), {});
    EXPECT_EQ(r.exitCode, 2);
    EXPECT_NE(r.err.find("bad.obj:4: face corner 9 names no vertex"), std::string::npos) << r.err;

    r = run(scene("--skip-barrier no-such-barrier --max-clusters 2"), {});
    EXPECT_EQ(r.exitCode, 2);
    EXPECT_NE(r.err.find("no barrier is named 'no-such-barrier'"), std::string::npos) << r.err;

    r = run(scene("--max-clusters 2"), {}, false);  // lavapipe alone lacks the extension
    EXPECT_EQ(r.exitCode, 3);
    EXPECT_NE(r.err.find("does not offer VK_NV_cluster_acceleration_structure"), std::string::npos)
        << r.err;

    r = run(scene("--help"), {}, false);
    EXPECT_EQ(r.exitCode, 0);
    EXPECT_NE(r.out.find("--skip-barrier"), std::string::npos);
}

}  // namespace
