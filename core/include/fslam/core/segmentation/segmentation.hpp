// Open-set segmentation of a feature-distilled Gaussian map (paper sec. "Novel-View Open-Set
// Segmentation"): instances found without a prompt by clustering the Gaussians in feature space
// and space, and objects selected by point or box prompts in a view, refined in 3D. Both give a
// label per Gaussian, so any view renders them: ids and masks are consistent across views by
// construction. docs/segmentation.md states the algorithm and its limits.
#pragma once

#include "fslam/core/segmentation/feature_graph.hpp"
#include "fslam/core/segmentation/instances.hpp"
#include "fslam/core/segmentation/label_rendering.hpp"
#include "fslam/core/segmentation/prompts.hpp"
