// SPDX-License-Identifier: Apache-2.0
// Moves of CLAS, templates and BLAS; references through old addresses become findings.
#include "embree_scene.h"
#include "execute_rig.h"

namespace clastrace::engine::execute_test {
namespace {

const auto kMove = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV;
const auto kImplicit = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
const auto kExplicit = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;

uint64_t move_infos(Rig& rig, const std::vector<uint64_t>& sources) {
    return rig.put_vec(rig.inputs, sources,
                       16);  // VkClusterAccelerationStructureMoveObjectsInfoNV is one address
}

struct Moved {
    std::vector<uint64_t> addresses;
    ExecutionRecord record;
};

Moved move_implicit(Rig& rig, const std::vector<uint64_t>& sources, ObjectDirectory& dir,
                    VkClusterAccelerationStructureTypeNV type =
                        VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV,
                    bool no_overlap = false) {
    CommandSetup s;
    setup_command(s, rig, kMove, kImplicit, uint32_t(sources.size()), move_infos(rig, sources));
    s.move.type = type;
    s.move.noMoveOverlap = no_overlap;
    ExecuteOptions o;
    o.directory = &dir;
    Moved m;
    m.record = execute(s.cmd, rig.memory, o);
    claim_implicit(rig, m.record);
    m.addresses = dst_addresses(rig, s.cmd, uint32_t(sources.size()));
    return m;
}

TEST(MoveObjects, MovedClasWorksAndOldAddressesBecomeFindings) {
    Rig rig(16);
    ObjectDirectory dir;
    ClusteredMesh m = icosphere_meshlets(3);
    auto clas = build_clas(rig, m, &dir);
    uint64_t old_blas = build_blas(rig, clas, &dir);
    Moved moved = move_implicit(rig, clas, dir);
    ASSERT_TRUE(moved.record.findings.empty()) << describe(moved.record.findings);
    // Tightly packed at clusterByteAlignment, same bytes.
    for (size_t i = 0; i < clas.size(); ++i) {
        EXPECT_EQ(moved.addresses[i] % EngineProperties{}.cluster_byte_alignment, 0u);
        EXPECT_EQ(rig.bytes(moved.addresses[i], moved.record.ops[i].dst_size),
                  rig.bytes(clas[i], moved.record.ops[i].dst_size));
    }
    // A BLAS over the new addresses traces like Embree; the old BLAS's references are stale.
    uint64_t new_blas = build_blas(rig, moved.addresses, &dir);
    expect_matches_embree(rig, new_blas, m, 0, &dir);
    Ray r{{0, 0, 3}, 0.0f, {0, 0, -1}, 100.0f};
    std::vector<Finding> trace_findings;
    BottomLevelHit h =
        trace_bottom_level_closest(rig.memory, new_blas, r, 0, &dir, &trace_findings);
    EXPECT_TRUE(h.hit.hit);
    EXPECT_TRUE(trace_findings.empty()) << describe(trace_findings);
    BottomLevelHit stale =
        trace_bottom_level_closest(rig.memory, old_blas, r, 0, &dir, &trace_findings);
    EXPECT_FALSE(stale.hit.hit);
    ASSERT_FALSE(trace_findings.empty());
    EXPECT_EQ(trace_findings[0].rule, kRuleStaleClusterReference);
    EXPECT_NE(trace_findings[0].message.find("moved away"), std::string::npos)
        << trace_findings[0].message;
    // Building a BLAS through the old addresses: one finding per reference, naming its index.
    std::vector<Finding> build_findings;
    build_blas(rig, {clas[0], moved.addresses[1], clas[2]}, &dir, &build_findings);
    ASSERT_EQ(count_rule(build_findings, kRuleStaleClusterReference), 2u)
        << describe(build_findings);
    EXPECT_NE(build_findings[0].message.find("clusterReferences[0]"), std::string::npos)
        << build_findings[0].message;
    EXPECT_NE(build_findings[1].message.find("clusterReferences[2]"), std::string::npos)
        << build_findings[1].message;
}

TEST(MoveObjects, NoMoveOverlapKeepsTheSourceValid) {
    Rig rig;
    ObjectDirectory dir;
    ClusteredMesh m = icosphere_meshlets(2);
    auto clas = build_clas(rig, m, &dir);
    Moved copy = move_implicit(rig, clas, dir,
                               VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV, true);
    ASSERT_TRUE(copy.record.findings.empty()) << describe(copy.record.findings);
    std::vector<Finding> f;
    build_blas(rig, clas, &dir, &f);
    EXPECT_TRUE(f.empty()) << describe(f);
    build_blas(rig, copy.addresses, &dir, &f);
    EXPECT_TRUE(f.empty()) << describe(f);
}

TEST(MoveObjects, MovedBlasAndTemplateWorkAtTheirNewAddress) {
    Rig rig(16);
    ObjectDirectory dir;
    ClusteredMesh m = icosphere_meshlets(3);
    auto clas = build_clas(rig, m, &dir);
    uint64_t blas = build_blas(rig, clas, &dir);
    // Explicit destination for the BLAS.
    uint64_t dst = Rig::alloc(rig.objects2, 1 << 20, 256);
    CommandSetup s;
    setup_command(s, rig, kMove, kExplicit, 1, move_infos(rig, {blas}));
    s.move.type = VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_CLUSTERS_BOTTOM_LEVEL_NV;
    rig.memory.write<uint64_t>(s.cmd.dstAddressesArray.deviceAddress, dst, {"test", -1});
    s.cmd.dstSizesArray = {};
    ExecuteOptions o;
    o.directory = &dir;
    ExecutionRecord r = execute(s.cmd, rig.memory, o);
    ASSERT_TRUE(r.findings.empty()) << describe(r.findings);
    EXPECT_EQ(r.ops[0].dst_address, dst);
    expect_matches_embree(rig, dst, m, 0, &dir);
    Ray ray{{0.1f, 0.2f, 3}, 0.0f, {0, 0, -1}, 100.0f};
    std::vector<Finding> f;
    BottomLevelHit moved_hit = trace_bottom_level_closest(rig.memory, dst, ray, 0, &dir, &f);
    EXPECT_TRUE(moved_hit.hit.hit);
    EXPECT_TRUE(f.empty()) << describe(f);
    EXPECT_FALSE(trace_bottom_level_closest(rig.memory, blas, ray, 0, &dir, &f).hit.hit);
    EXPECT_EQ(count_rule(f, kRuleNotABottomLevel), 1u) << describe(f);

    // A template moved, then instantiated from its new address; the old one is a finding.
    uint64_t tinfos = upload_cluster_infos(rig, m, true);
    CommandSetup ts;
    setup_command(ts, rig,
                  VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV,
                  kImplicit, 1, tinfos);
    ExecutionRecord tr = execute(ts.cmd, rig.memory, o);
    ASSERT_TRUE(tr.findings.empty()) << describe(tr.findings);
    claim_implicit(rig, tr);
    uint64_t tmpl = dst_addresses(rig, ts.cmd, 1)[0];
    Moved mt = move_implicit(rig, {tmpl}, dir,
                             VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_TEMPLATE_NV);
    ASSERT_TRUE(mt.record.findings.empty()) << describe(mt.record.findings);
    EXPECT_EQ(mt.addresses[0] % EngineProperties{}.cluster_template_byte_alignment, 0u);
    for (uint64_t t : {mt.addresses[0], tmpl}) {
        VkClusterAccelerationStructureInstantiateClusterInfoNV inst{};
        inst.clusterTemplateAddress = t;
        inst.vertexBuffer = {rig.put_vec(rig.inputs, m.clusters[0].positions, 16), 12};
        CommandSetup is;
        setup_command(is, rig,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV,
                      kImplicit, 1, rig.put(rig.inputs, &inst, sizeof inst, 16));
        ExecutionRecord ir = execute(is.cmd, rig.memory, o);
        claim_implicit(rig, ir);
        if (t == tmpl) {
            EXPECT_EQ(count_rule(ir.findings, kRuleNotATemplate), 1u) << describe(ir.findings);
            EXPECT_FALSE(ir.ops[0].executed);
        } else {
            EXPECT_TRUE(ir.findings.empty()) << describe(ir.findings);
            EXPECT_TRUE(ir.ops[0].executed);
        }
    }
}

TEST(MoveObjects, SwapInOneCommandIsDeterministicAndFlagged) {
    Rig rig;
    ObjectDirectory dir;
    ClusteredMesh m = icosphere_meshlets(3);
    auto clas = build_clas(rig, m, &dir);
    // Two CLAS of equal alignment, swapped by explicit moves: a cycle A->B, B->A.
    uint64_t a = clas[0], b = clas[1];
    auto bytes_a = rig.bytes(a, rig.get<uint32_t>(a + 8));
    auto bytes_b = rig.bytes(b, rig.get<uint32_t>(b + 8));
    CommandSetup s;
    setup_command(s, rig, kMove, kExplicit, 2, move_infos(rig, {a, b}));
    rig.memory.write<uint64_t>(s.cmd.dstAddressesArray.deviceAddress, b, {"test", -1});
    rig.memory.write<uint64_t>(s.cmd.dstAddressesArray.deviceAddress + 8, a, {"test", -1});
    s.cmd.dstSizesArray = {};
    ExecuteOptions o;
    o.directory = &dir;
    ExecutionRecord r = execute(s.cmd, rig.memory, o);
    EXPECT_GE(count_rule(r.findings, kRuleIntraCommandHazard), 2u) << describe(r.findings);
    // Every read happened before every write: a clean swap (bytes beyond the smaller object
    // are overwritten by the larger one, which is what a GPU copy would do too).
    EXPECT_EQ(rig.bytes(b, bytes_a.size()), bytes_a);
    EXPECT_EQ(rig.bytes(a, 16), std::vector<std::byte>(bytes_b.begin(), bytes_b.begin() + 16));
    std::vector<Finding> f;
    build_blas(rig, {b}, &dir, &f);
    EXPECT_TRUE(f.empty()) << describe(f);
}

TEST(MoveObjects, BadSourcesAndLimitsAreFindings) {
    Rig rig;
    ObjectDirectory dir;
    ClusteredMesh m = icosphere_meshlets(2);
    auto clas = build_clas(rig, m, &dir);
    uint64_t blas = build_blas(rig, clas, &dir);
    // Not an object; a BLAS moved as a CLAS; total above maxMovedBytes.
    CommandSetup s;
    setup_command(s, rig, kMove, kImplicit, 3, move_infos(rig, {rig.inputs.base, blas, clas[0]}));
    s.move.maxMovedBytes = 16;
    ExecuteOptions o;
    o.directory = &dir;
    ExecutionRecord r = execute(s.cmd, rig.memory, o);
    EXPECT_EQ(
        count_rule(
            r.findings,
            "VUID-VkClusterAccelerationStructureMoveObjectsInfoNV-srcAccelerationStructure-10483"),
        1u)
        << describe(r.findings);
    EXPECT_EQ(count_rule(r.findings, kRuleMoveTypeMismatch), 1u) << describe(r.findings);
    EXPECT_EQ(count_rule(r.findings, kRuleMovedBytesAboveInput), 1u) << describe(r.findings);
    EXPECT_FALSE(r.ops[0].executed);
    EXPECT_FALSE(r.ops[1].executed);
    EXPECT_TRUE(r.ops[2].executed);
    // In implicit mode a failed op's address and size read back as 0.
    EXPECT_EQ(rig.get<uint64_t>(s.cmd.dstAddressesArray.deviceAddress), 0u);
    EXPECT_EQ(rig.get<uint32_t>(s.cmd.dstSizesArray.deviceAddress), 0u);
}

TEST(MoveObjects, OverwrittenClasIsAFinding) {
    Rig rig;
    ObjectDirectory dir;
    ClusteredMesh m = icosphere_meshlets(3);
    auto clas = build_clas(rig, m, &dir);
    // A valid CLAS copied over another (as a stray write would): the hash differs.
    auto other = rig.bytes(clas[1], rig.get<uint32_t>(clas[1] + 8));
    std::memcpy(rig.memory.write_bytes(clas[0], 64, {"test", -1}).data(), other.data(), 64);
    // Garbage over a third.
    rig.memory.write<uint32_t>(clas[2], 0xdeadbeef, {"test", -1});
    std::vector<Finding> f;
    build_blas(rig, {clas[0], clas[1], clas[2]}, &dir, &f);
    ASSERT_EQ(count_rule(f, kRuleStaleClusterReference), 2u) << describe(f);
    EXPECT_NE(f[0].message.find("overwritten"), std::string::npos) << f[0].message;
    EXPECT_NE(f[1].message.find("clusterReferences[2]"), std::string::npos) << f[1].message;
}

}  // namespace
}  // namespace clastrace::engine::execute_test
