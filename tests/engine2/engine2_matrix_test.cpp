#include "engine2_test_util.h"
