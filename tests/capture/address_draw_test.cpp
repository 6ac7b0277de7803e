// SPDX-License-Identifier: Apache-2.0
// Draws that may write through buffer device addresses, captured on lavapipe: tests/apps'
// address_draw_app draws with a pipeline whose vertex shader writes through an address, then
// with one whose shader reaches no memory. The capture (debug JSON) records the first draw as
// a Draw with the vertex stage and not the second; with CLASTRACE_DEVICE_ADDRESS_WRITES=off it
// records neither; with exact, the first draw as in cheap mode (exact compares dispatches only).
#include "layer_launch_test.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <vulkan/vulkan_core.h>

namespace {

using nlohmann::json;
using namespace clastrace::layer_launch;

class AddressDraws : public LayerLaunchTest {
public:
    AddressDraws() : LayerLaunchTest("clastrace_address_draws") {}

    // The Draw commands of every recorded command buffer.
    std::vector<json> captured_draws(std::map<std::string, std::string> env,
                                     std::string* err = nullptr) {
        env["CLASTRACE_DEBUG_JSON"] = (dir / "capture.json").string();
        ProcessResult r = run(ADDRESS_DRAW_APP, env);
        if (err) *err = r.err;
        EXPECT_EQ(r.exitCode, 0) << r.err;
        EXPECT_EQ(r.out, "ok\n");  // the shader wrote through the address under the layer too
        std::vector<json> draws;
        const json captured = json::parse(readText(dir / "capture.json"));
        for (const json& cb : captured.value("commandBuffers", json::array()))
            for (const json& command : cb["commands"])
                if (command["kind"] == "Draw") draws.push_back(command);
        return draws;
    }
};

TEST_F(AddressDraws, OnlyTheDrawWhoseShaderUsesAddressesIsRecorded) {
    const std::vector<json> draws = captured_draws({});
    ASSERT_EQ(draws.size(), 1u);
    EXPECT_EQ(draws[0]["entryPoint"], "vkCmdDraw");
    EXPECT_EQ(draws[0]["addressStages"].get<uint64_t>(),
              uint64_t(VK_PIPELINE_STAGE_2_VERTEX_SHADER_BIT));
    EXPECT_NE(draws[0]["pipeline"].get<uint64_t>(), 0u);
}

TEST_F(AddressDraws, ModeOffRecordsNoDraw) {
    EXPECT_TRUE(captured_draws({{"CLASTRACE_DEVICE_ADDRESS_WRITES", "off"}}).empty());
}

// Exact mode compares memory around dispatches only: the draw is recorded as in cheap mode (a
// possible writer), and the layer says so once at CLASTRACE_LOG=info.
TEST_F(AddressDraws, ExactModeKeepsDrawsCheapAndSaysSoOnce) {
    std::string err;
    const std::vector<json> draws =
        captured_draws({{"CLASTRACE_DEVICE_ADDRESS_WRITES", "exact"}, {"CLASTRACE_LOG", "info"}},
                       &err);
    ASSERT_EQ(draws.size(), 1u);
    EXPECT_EQ(draws[0]["addressStages"].get<uint64_t>(),
              uint64_t(VK_PIPELINE_STAGE_2_VERTEX_SHADER_BIT));
    const std::string said =
        "draws (vkCmdDraw) whose shaders may write through device addresses "
        "are recorded as in cheap mode";
    const size_t at = err.find(said);
    EXPECT_NE(at, std::string::npos) << err;
    EXPECT_EQ(err.find(said, at + 1), std::string::npos) << err;  // once
}

}  // namespace
