#!/bin/sh
# SPDX-License-Identifier: Apache-2.0
# Runs a program ("$@") on the test driver, for the ctest entries that start a Vulkan program
# directly: the driver CLASTRACE_TEST_DRIVER_FILES names, with CLASTRACE_TEST_DRIVER_LIBRARY_PATH
# before LD_LIBRARY_PATH (as include/clastrace/testsupport/test_driver.h gives its programs);
# unset, the loader's own search, which finds the system's lavapipe where no GPU driver answers.
if [ -n "${CLASTRACE_TEST_DRIVER_FILES:-}" ]; then
  unset VK_ICD_FILENAMES
  VK_DRIVER_FILES=$CLASTRACE_TEST_DRIVER_FILES
  export VK_DRIVER_FILES
  if [ -n "${CLASTRACE_TEST_DRIVER_LIBRARY_PATH:-}" ]; then
    LD_LIBRARY_PATH=$CLASTRACE_TEST_DRIVER_LIBRARY_PATH${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
    export LD_LIBRARY_PATH
  fi
fi
exec "$@"
