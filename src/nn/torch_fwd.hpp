#pragma once
// The one place src/nn includes LibTorch (also the target's precompiled header).
#include <torch/torch.h>
