// SPDX-License-Identifier: Apache-2.0
// Bug: one command buffer builds cluster templates at addresses the host chose, then
// instantiates every template (INSTANTIATE_TRIANGLE_CLUSTER) by those addresses with no barrier between, so the second command may read a
// template before its build is done. --fixed records BUILD/AS_WRITE -> BUILD/AS_READ between.
#include "bug_templates.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "template_instantiate_no_barrier");
    const Quads quads = make_quads(gpu, 3);
    TemplateStep templates;
    prepare_template_build(gpu, quads, templates);
    TemplateStep reader;
    prepare_instantiation(gpu, quads, templates, reader);

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &templates.info);
    if (fixed) build_to_build_barrier(cb);
    gpu.cmd_build_clusters(cb, &reader.info);
    gpu.submit_and_wait(cb);
    print_range("templates", template_address(templates, 0), templates.slot * quads.count);
    return 0;
}
