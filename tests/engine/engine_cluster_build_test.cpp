#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/cluster_format.h"
#include "clastrace/engine/traversal.h"
#include "engine_test_util.h"

#include <gtest/gtest.h>

namespace clastrace::engine {
namespace {

using test::Arena;

TEST(ClusterBuild, GridBuildsAndTraces) {
  Arena arena;
  const test::Mesh m = test::grid(8);
  auto info = test::cluster_info(arena, m);
  const ClusterObject o = build_triangle_cluster(arena.memory, info, test::default_input(), EngineProperties{}, 0);
  ASSERT_TRUE(o.ok);
  EXPECT_TRUE(o.findings.empty()) << o.findings[0].message;
  ASSERT_EQ(object_size_from_header(o.bytes), o.bytes.size());
  Ray ray{{3.5f, 2.5f, 5.0f}, 0.0f, {0.0f, 0.0f, -1.0f}, 100.0f};
  const Hit h = trace_closest(o.bytes, ray, 0);
  ASSERT_TRUE(h.hit);
  EXPECT_NEAR(h.t, 5.0f, 0.25f);
  EXPECT_EQ(h.cluster_id, 7u);
}

}  // namespace
}  // namespace clastrace::engine
