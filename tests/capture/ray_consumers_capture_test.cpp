// SPDX-License-Identifier: Apache-2.0
// The commands that read acceleration structures, captured for real: tests/apps'
// ray_consumers_app builds a BLAS and a TLAS on lavapipe 25, then runs a ray-query dispatch over
// the TLAS bound in a descriptor set (its address also in the push constants), the same with a
// set written through an update template and with pushed descriptors, a plain dispatch, a draw
// whose vertex shader runs the ray query,
// vkCmdTraceRaysKHR and vkCmdTraceRaysIndirectKHR, under the capture layer. The trace's records
// must say which dispatch uses ray queries, the rays' entry points, dimensions, tables and
// indirect address, and for each consumer the TLAS by handle and address with set, binding and
// source. In "sources" mode the app binds and pushes with VK_KHR_maintenance6 and rewrites an
// UPDATE_AFTER_BIND set between recording and submission; in "descriptor-buffer" mode the TLAS
// descriptor lives in a descriptor buffer; in "address-in-buffer" mode the shader reads the TLAS
// address from a storage buffer (and, in one dispatch, from a dynamic uniform buffer). Label
// rt-driver: skipped where lavapipe 25 is not unpacked.
#include "layer_launch_test.h"

#include <clastrace/testsupport/test_driver.h>
#include <clastrace/traces/trace_reader.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <vulkan/vulkan_core.h>

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using namespace clastrace::layer_launch;

constexpr uint32_t kSourceDescriptorSet = 0;
constexpr uint32_t kSourcePushDescriptor = 1;
constexpr uint32_t kSourceDescriptorBuffer = 2;
constexpr uint32_t kSourcePushConstants = 3;
constexpr uint32_t kSourceMemory = 4;

struct Binding {
    uint32_t set = 0, binding = 0, array_element = 0, source = 0;
    uint64_t acceleration_structure = 0, address = 0;
};

struct Dispatch {
    uint64_t pipeline = 0;
    bool ray_query = false;
    std::vector<Binding> structures;
    size_t storage_buffers = 0;
};

struct Draw {
    std::string entry_point;
    uint64_t pipeline = 0, address_stages = 0, ray_query_stages = 0;
    std::vector<Binding> structures;
};

struct Rays {
    std::string entry_point;
    uint64_t pipeline = 0, indirect_address = 0, raygen_address = 0;
    uint32_t width = 0, height = 0, depth = 0;
    size_t storage_buffers = 0;
    std::vector<Binding> structures;
    std::vector<std::pair<uint64_t, uint64_t>> inputs;  // (address, size) of each snapshot
};

template <typename Vector>
std::vector<Binding> bindings_of(const Vector* list) {
    std::vector<Binding> out;
    if (!list) return out;
    for (const auto* b : *list)
        out.push_back({b->set(), b->binding(), b->array_element(), b->source(),
                       b->acceleration_structure(), b->address()});
    return out;
}

class RayConsumersCapture : public LayerLaunchTest {
protected:
    RayConsumersCapture() : LayerLaunchTest("clastrace_ray_consumers") {}

    void SetUp() override {
        LayerLaunchTest::SetUp();
        if (IsSkipped()) return;
        driver = clastrace::testsupport::ray_tracing_driver();
        if (!driver) GTEST_SKIP() << clastrace::testsupport::kNoRayTracingDriver;
        trace = dir / "rays.clt";
    }

    // The app under the capture layer on lavapipe 25; then reads what it says and the trace.
    void capture(const std::string& mode = "") {
        // The driver inside the command: the layer launch puts the suite's test driver first.
        ProcessResult r =
            run("env" + driver->environment_words() + " " + RAY_CONSUMERS_APP + " " +
                    quote((dir / "out.json").string()) + (mode.empty() ? "" : " " + mode),
                {{"CLASTRACE_CAPTURE", "1"}, {"CLASTRACE_OUTPUT", trace.string()}});
        ASSERT_EQ(r.exitCode, 0) << r.out << r.err;
        EXPECT_EQ(r.out, "ok\n");
        out = json::parse(readText(dir / "out.json"));
        read_trace();
    }

    void read_trace() {
        clastrace::traces::TraceError error;
        auto reader = clastrace::traces::TraceReader::open(trace.string(), &error);
        ASSERT_TRUE(reader) << error.message;
        clastrace::traces::RecordView view;
        while (reader->next(&view)) {
            if (view.kind == clastrace::fbs::RecordBody::CmdDispatch) {
                const auto* c = view.record->body_as_CmdDispatch();
                dispatches.push_back({c->pipeline(), c->ray_query(),
                                      bindings_of(c->acceleration_structures()),
                                      c->storage_buffers() ? c->storage_buffers()->size() : 0});
            } else if (view.kind == clastrace::fbs::RecordBody::CmdDraw) {
                const auto* c = view.record->body_as_CmdDraw();
                draws.push_back({c->entry_point() ? c->entry_point()->str() : "", c->pipeline(),
                                 c->address_stages(), c->ray_query_stages(),
                                 bindings_of(c->acceleration_structures())});
            } else if (view.kind == clastrace::fbs::RecordBody::CmdTraceRays) {
                const auto* c = view.record->body_as_CmdTraceRays();
                Rays r;
                r.entry_point = c->entry_point() ? c->entry_point()->str() : "";
                r.pipeline = c->pipeline();
                r.indirect_address = c->indirect_address();
                if (c->shader_binding_tables() && c->shader_binding_tables()->size() == 4)
                    r.raygen_address = c->shader_binding_tables()->Get(0)->device_address();
                r.width = c->width();
                r.height = c->height();
                r.depth = c->depth();
                r.storage_buffers = c->storage_buffers() ? c->storage_buffers()->size() : 0;
                r.structures = bindings_of(c->acceleration_structures());
                if (c->inputs())
                    for (const auto* snapshot : *c->inputs())
                        r.inputs.push_back({snapshot->address(), snapshot->size()});
                rays.push_back(r);
            }
        }
    }

    // The TLAS bound at set 0, binding 0, then found again in the push constants at offset 0.
    void expect_the_top_level(const std::vector<Binding>& structures,
                              uint32_t source = kSourceDescriptorSet) {
        ASSERT_EQ(structures.size(), 2u);
        const uint64_t top = out["topLevel"], address = out["topLevelAddress"];
        EXPECT_NE(address, 0u);
        EXPECT_EQ(structures[0].source, source);
        EXPECT_EQ(structures[0].set, 0u);
        EXPECT_EQ(structures[0].binding, 0u);
        EXPECT_EQ(structures[0].array_element, 0u);
        EXPECT_EQ(structures[0].acceleration_structure, top);
        EXPECT_EQ(structures[0].address, address);
        EXPECT_EQ(structures[1].source, kSourcePushConstants);
        EXPECT_EQ(structures[1].array_element, 0u);  // the byte offset in the push constants
        EXPECT_EQ(structures[1].acceleration_structure, top);
        EXPECT_EQ(structures[1].address, address);
    }

    std::optional<clastrace::testsupport::TestDriver> driver;
    fs::path trace;
    json out;
    std::vector<Dispatch> dispatches;
    std::vector<Draw> draws;
    std::vector<Rays> rays;
};

TEST_F(RayConsumersCapture, RayQueryDispatchReachesTheBoundTopLevelAndThePlainOneNothing) {
    capture();
    ASSERT_EQ(dispatches.size(), 4u);
    for (size_t i = 0; i < 2; ++i) {  // a set written with vkUpdateDescriptorSets, a template
        SCOPED_TRACE(i);
        EXPECT_EQ(dispatches[i].pipeline, out["rayQueryPipeline"].get<uint64_t>());
        EXPECT_TRUE(dispatches[i].ray_query);
        expect_the_top_level(dispatches[i].structures);
    }
    EXPECT_EQ(dispatches[2].pipeline, out["pushedRayQueryPipeline"].get<uint64_t>());
    EXPECT_TRUE(dispatches[2].ray_query);
    expect_the_top_level(dispatches[2].structures, kSourcePushDescriptor);
    EXPECT_EQ(dispatches[3].pipeline, out["plainPipeline"].get<uint64_t>());
    EXPECT_FALSE(dispatches[3].ray_query);
    EXPECT_TRUE(dispatches[3].structures.empty());
}

// A draw is recorded for its vertex shader's ray query alone (no address writes), with the
// stage and what the graphics bind point reaches.
TEST_F(RayConsumersCapture, RayQueryDrawIsRecordedWithItsStageAndTheTopLevel) {
    capture();
    ASSERT_EQ(draws.size(), 1u);
    EXPECT_EQ(draws[0].entry_point, "vkCmdDraw");
    EXPECT_EQ(draws[0].pipeline, out["drawPipeline"].get<uint64_t>());
    EXPECT_EQ(draws[0].address_stages, 0u);
    EXPECT_EQ(draws[0].ray_query_stages, uint64_t(VK_PIPELINE_STAGE_2_VERTEX_SHADER_BIT));
    expect_the_top_level(draws[0].structures);
}

TEST_F(RayConsumersCapture, TraceRaysRecordsEntryPointDimensionsTablesAndTheTopLevel) {
    capture();
    const bool indirect = out["indirect"];
    ASSERT_EQ(rays.size(), indirect ? 2u : 1u);
    const Rays& direct = rays[0];
    EXPECT_EQ(direct.entry_point, "vkCmdTraceRaysKHR");
    EXPECT_EQ(direct.pipeline, out["rayTracingPipeline"].get<uint64_t>());
    EXPECT_EQ(direct.width, 4u);
    EXPECT_EQ(direct.height, 2u);
    EXPECT_EQ(direct.depth, 1u);
    EXPECT_EQ(direct.indirect_address, 0u);
    EXPECT_EQ(direct.raygen_address, out["raygenAddress"].get<uint64_t>());
    EXPECT_EQ(direct.storage_buffers, 1u);  // the results, bound at the ray-tracing bind point
    EXPECT_TRUE(direct.inputs.empty());
    expect_the_top_level(direct.structures);
    if (!indirect) return;
    const Rays& from_memory = rays[1];
    EXPECT_EQ(from_memory.entry_point, "vkCmdTraceRaysIndirectKHR");
    EXPECT_EQ(from_memory.indirect_address, out["indirectAddress"].get<uint64_t>());
    EXPECT_EQ(from_memory.width, 0u);  // read by the device: in the record's inputs
    ASSERT_EQ(from_memory.inputs.size(), 1u);
    EXPECT_EQ(from_memory.inputs[0].first, from_memory.indirect_address);
    EXPECT_EQ(from_memory.inputs[0].second, sizeof(VkTraceRaysIndirectCommandKHR));
    EXPECT_EQ(from_memory.raygen_address, out["raygenAddress"].get<uint64_t>());
    expect_the_top_level(from_memory.structures);
}

// VK_KHR_maintenance6: vkCmdBindDescriptorSets2KHR, vkCmdPushConstants2KHR and
// vkCmdPushDescriptorSet2KHR feed the same state as their 1.0 forms. A set created
// UPDATE_AFTER_BIND and rewritten between recording and submission: the dispatch reaches what the
// set names at submission, not at binding.
TEST_F(RayConsumersCapture, InfoStructFormsAndSetsUpdatedAfterBindReachTheTopLevel) {
    capture("sources");
    ASSERT_EQ(dispatches.size(), 3u);
    EXPECT_EQ(dispatches[0].pipeline, out["rayQueryPipeline"].get<uint64_t>());
    expect_the_top_level(dispatches[0].structures);
    EXPECT_EQ(dispatches[1].pipeline, out["updateAfterBindPipeline"].get<uint64_t>());
    ASSERT_EQ(dispatches[1].structures.size(), 1u);
    const Binding& late = dispatches[1].structures[0];
    EXPECT_EQ(late.source, kSourceDescriptorSet);
    EXPECT_EQ(late.set, 0u);
    EXPECT_EQ(late.binding, 0u);
    EXPECT_NE(late.acceleration_structure, out["otherTopLevel"].get<uint64_t>());
    EXPECT_EQ(late.acceleration_structure, out["topLevel"].get<uint64_t>());
    EXPECT_EQ(late.address, out["topLevelAddress"].get<uint64_t>());
    // vkCmdPushDescriptorSet2KHR: the pushed TLAS (no push constants in that command buffer).
    EXPECT_EQ(dispatches[2].pipeline, out["pushedRayQueryPipeline"].get<uint64_t>());
    ASSERT_EQ(dispatches[2].structures.size(), 1u);
    const Binding& pushed = dispatches[2].structures[0];
    EXPECT_EQ(pushed.source, kSourcePushDescriptor);
    EXPECT_EQ(pushed.set, 0u);
    EXPECT_EQ(pushed.binding, 0u);
    EXPECT_EQ(pushed.acceleration_structure, out["topLevel"].get<uint64_t>());
    EXPECT_EQ(pushed.address, out["topLevelAddress"].get<uint64_t>());
}

// VK_EXT_descriptor_buffer: the TLAS descriptor, asked of vkGetDescriptorEXT and copied into a
// descriptor buffer at the set layout's binding offset, the set bound at a non-zero offset. The
// capture reads the buffer and names the TLAS by handle and address at set 0, binding 0.
TEST_F(RayConsumersCapture, DescriptorBufferReachesTheTopLevelItsDescriptorNames) {
    capture("descriptor-buffer");
    ASSERT_EQ(dispatches.size(), 1u);
    EXPECT_EQ(dispatches[0].pipeline, out["descriptorBufferPipeline"].get<uint64_t>());
    EXPECT_TRUE(dispatches[0].ray_query);
    ASSERT_EQ(dispatches[0].structures.size(), 1u);
    const Binding& found = dispatches[0].structures[0];
    EXPECT_EQ(found.source, kSourceDescriptorBuffer);
    EXPECT_EQ(found.set, 0u);
    EXPECT_EQ(found.binding, 0u);
    EXPECT_EQ(found.array_element, 0u);
    EXPECT_EQ(found.acceleration_structure, out["topLevel"].get<uint64_t>());
    EXPECT_EQ(found.address, out["topLevelAddress"].get<uint64_t>());
}

// A shader that turns a uint64_t from a storage buffer into the TLAS: the capture finds the
// TLAS address in the bound buffer (source 4, set 0, binding 0, byte offset 0 in
// array_element), also in a pushed buffer that got the address only after recording (read
// again at submission), also in a uniform buffer bound with a dynamic offset (the offset of
// 256 applied: the address is at byte 0 of the bound range); a buffer whose bytes equal no
// structure's address gives no entry.
TEST_F(RayConsumersCapture, AddressStoredInABoundBufferReachesTheTopLevel) {
    capture("address-in-buffer");
    ASSERT_EQ(dispatches.size(), 4u);
    const uint64_t top = out["topLevel"], address = out["topLevelAddress"];
    const char* const pipelines[] = {"addressPipeline", "addressPipeline", "pushedAddressPipeline",
                                     "uniformAddressPipeline"};
    for (size_t i : {0u, 2u, 3u}) {
        SCOPED_TRACE(i);
        EXPECT_EQ(dispatches[i].pipeline, out[pipelines[i]].get<uint64_t>());
        EXPECT_TRUE(dispatches[i].ray_query);
        ASSERT_EQ(dispatches[i].structures.size(), 1u);
        const Binding& found = dispatches[i].structures[0];
        EXPECT_EQ(found.source, kSourceMemory);
        EXPECT_EQ(found.set, 0u);
        EXPECT_EQ(found.binding, 0u);
        EXPECT_EQ(found.array_element, 0u);  // the byte offset in the bound range
        EXPECT_EQ(found.acceleration_structure, top);
        EXPECT_EQ(found.address, address);
    }
    // The uniform buffer is searched, not recorded among the dispatch's storage buffers.
    EXPECT_EQ(dispatches[3].storage_buffers, 1u);
    EXPECT_EQ(dispatches[1].pipeline, out["addressPipeline"].get<uint64_t>());
    EXPECT_TRUE(dispatches[1].ray_query);
    EXPECT_TRUE(dispatches[1].structures.empty());
}

}  // namespace
