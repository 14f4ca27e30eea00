#include "fslam/core/eval/image_metrics.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "fslam/core/math/ssim.hpp"

namespace fslam::core {
namespace {

TEST(ImageMetrics, PsnrByHand) {
  // One of four 8-bit pixels off by 10: MSE = 100 / 4 = 25, PSNR = 10 log10(255^2 / 25)
  // = 10 log10(2601) = 34.151404 dB. The float copy in [0, 1] (L = 1) gives the same.
  const cv::Mat a = (cv::Mat_<uchar>(2, 2) << 0, 0, 0, 0);
  const cv::Mat b = (cv::Mat_<uchar>(2, 2) << 10, 0, 0, 0);
  double psnr = 0.0;
  std::string why;
  ASSERT_TRUE(compute_psnr(a, b, ImageMetricsConfig{}, &psnr, &why)) << why;
  EXPECT_NEAR(psnr, 34.151404, 1e-6);
  cv::Mat af, bf;
  a.convertTo(af, CV_32F, 1.0 / 255.0);
  b.convertTo(bf, CV_32F, 1.0 / 255.0);
  ASSERT_TRUE(compute_psnr(af, bf, ImageMetricsConfig{}, &psnr, &why)) << why;
  EXPECT_NEAR(psnr, 34.151404, 1e-5);

  // Colour: the mean runs over pixels and channels. 2x1 RGB, one channel of one pixel off by
  // 0.1: MSE = 0.01 / 6, PSNR = 10 log10(600) = 27.781513 dB.
  const cv::Mat c(1, 2, CV_32FC3, cv::Scalar(0.5f, 0.5f, 0.5f));
  cv::Mat d = c.clone();
  d.at<cv::Vec3f>(0, 1)[2] = 0.6f;
  ASSERT_TRUE(compute_psnr(c, d, ImageMetricsConfig{}, &psnr, &why)) << why;
  EXPECT_NEAR(psnr, 27.781513, 1e-4);  // float input: 0.6f - 0.5f is not exactly 0.1

  ASSERT_TRUE(compute_psnr(a, a, ImageMetricsConfig{}, &psnr, &why)) << why;
  EXPECT_EQ(psnr, std::numeric_limits<double>::infinity());
  EXPECT_FALSE(compute_psnr(a, af, ImageMetricsConfig{}, &psnr, &why));
  EXPECT_NE(why.find("differ"), std::string::npos) << why;
}

TEST(ImageMetrics, SsimWindowOfOnePixelByHand) {
  // A 1x1 window has no variance: SSIM = (2xy + C1) / (x^2 + y^2 + C1). x = 0.5, y = 0.25,
  // C1 = 1e-4: 0.2501 / 0.3126 = 0.80006398.
  const cv::Mat x(2, 2, CV_32FC1, cv::Scalar(0.5f)), y(2, 2, CV_32FC1, cv::Scalar(0.25f));
  ImageMetricsConfig config;
  config.ssim_window = 1;
  double ssim = 0.0;
  std::string why;
  ASSERT_TRUE(compute_ssim(x, y, config, &ssim, &why)) << why;
  EXPECT_NEAR(ssim, 0.80006398, 1e-6);
}

TEST(ImageMetrics, SsimZeroPaddedBorderByHand) {
  // 3x3 images, constant x = 0.6 and y = 0.3, window 3 with sigma 1.5:
  // taps exp(-1/4.5) = 0.8007374, 1, 0.8007374 -> normalised w = (0.3078013, 0.3843973, 0.3078013).
  // Zero padding: a window keeps weight S inside the image and reads 0 outside, so
  // mu_x = 0.6 S, var_x = 0.36 S (1 - S), var_y = 0.09 S (1 - S), cov = 0.18 S (1 - S).
  //   centre: S = 1 -> SSIM = (2 0.18 + C1) / (0.45 + C1) = 0.80004443
  //   edges:  S = w0 + w1 = 0.6921987 -> SSIM = 0.64156230
  //   corners: S = 0.6921987^2 = 0.4791390 -> SSIM = 0.64142707
  //   mean = (0.80004443 + 4 * 0.64156230 + 4 * 0.64142707) / 9 = 0.65911133
  // A replicate-border convention would give 0.80004443 everywhere.
  const cv::Mat x(3, 3, CV_32FC1, cv::Scalar(0.6f)), y(3, 3, CV_32FC1, cv::Scalar(0.3f));
  ImageMetricsConfig config;
  config.ssim_window = 3;
  double ssim = 0.0;
  cv::Mat map;
  std::string why;
  ASSERT_TRUE(compute_ssim(x, y, config, &ssim, &why, &map)) << why;
  EXPECT_NEAR(map.at<double>(1, 1), 0.80004443, 1e-6);
  EXPECT_NEAR(map.at<double>(0, 1), 0.64156230, 1e-6);
  EXPECT_NEAR(map.at<double>(2, 2), 0.64142707, 1e-6);
  EXPECT_NEAR(ssim, 0.65911133, 1e-6);

  // 8-bit input uses L = 255: the same as the float image divided by 255.
  const cv::Mat x8(3, 3, CV_8UC1, cv::Scalar(153)), y8(3, 3, CV_8UC1, cv::Scalar(76));
  double ssim8 = 0.0, ssim_float = 0.0;
  ASSERT_TRUE(compute_ssim(x8, y8, config, &ssim8, &why)) << why;
  ASSERT_TRUE(compute_ssim(cv::Mat(3, 3, CV_32FC1, cv::Scalar(153.0f / 255.0f)),
                           cv::Mat(3, 3, CV_32FC1, cv::Scalar(76.0f / 255.0f)), config,
                           &ssim_float, &why))
      << why;
  EXPECT_NEAR(ssim8, ssim_float, 1e-6);
}

TEST(ImageMetrics, SsimMatchesPerPixelHeaderMath) {
  // The CPU path (separable filtering) and the per-pixel device math agree, 3 channels, with the
  // default 11x11 window wider than the image in one direction.
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> uniform(0.0f, 1.0f);
  const int w = 13, h = 9;
  cv::Mat x(h, w, CV_32FC3), y(h, w, CV_32FC3);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u)
      for (int c = 0; c < 3; ++c) {
        x.at<cv::Vec3f>(v, u)[c] = uniform(rng);
        y.at<cv::Vec3f>(v, u)[c] = 0.7f * x.at<cv::Vec3f>(v, u)[c] + 0.3f * uniform(rng);
      }
  double ssim = 0.0;
  cv::Mat map;
  std::string why;
  ASSERT_TRUE(compute_ssim(x, y, ImageMetricsConfig{}, &ssim, &why, &map)) << why;
  ASSERT_EQ(map.type(), CV_64FC3);

  // Planar copies [3, h, w] for the per-pixel math, in double (as the evaluation runs) and in
  // float (as kernels and the loss run; on textured data float agrees to 1e-5).
  std::vector<double> xd(static_cast<std::size_t>(3 * w * h)), yd(xd.size());
  for (int c = 0; c < 3; ++c)
    for (int v = 0; v < h; ++v)
      for (int u = 0; u < w; ++u) {
        xd[static_cast<std::size_t>((c * h + v) * w + u)] = x.at<cv::Vec3f>(v, u)[c];
        yd[static_cast<std::size_t>((c * h + v) * w + u)] = y.at<cv::Vec3f>(v, u)[c];
      }
  const std::vector<float> xf(xd.begin(), xd.end()), yf(yd.begin(), yd.end());
  double wd[math::kSsimWindow];
  float wf[math::kSsimWindow];
  math::ssim_gaussian_window(math::kSsimWindow, static_cast<double>(math::kSsimSigma), wd);
  math::ssim_gaussian_window(math::kSsimWindow, math::kSsimSigma, wf);
  EXPECT_NEAR(std::accumulate(wd, wd + math::kSsimWindow, 0.0), 1.0, 1e-15);
  double sum = 0.0;
  for (int c = 0; c < 3; ++c)
    for (int v = 0; v < h; ++v)
      for (int u = 0; u < w; ++u) {
        const double s = math::ssim_pixel(xd.data(), yd.data(), w, h, u, v, c, wd,
                                          math::kSsimWindow, math::ssim_c1(1.0),
                                          math::ssim_c2(1.0));
        const float sf = math::ssim_pixel(xf.data(), yf.data(), w, h, u, v, c, wf,
                                          math::kSsimWindow, math::ssim_c1(1.0f),
                                          math::ssim_c2(1.0f));
        EXPECT_NEAR(s, map.at<cv::Vec3d>(v, u)[c], 1e-12) << u << "," << v << "," << c;
        EXPECT_NEAR(sf, s, 1e-5) << u << "," << v << "," << c;
        sum += s;
      }
  EXPECT_NEAR(ssim, sum / (3 * w * h), 1e-12);

  ASSERT_TRUE(compute_ssim(x, x, ImageMetricsConfig{}, &ssim, &why)) << why;
  EXPECT_NEAR(ssim, 1.0, 1e-6);
}

TEST(ImageMetrics, DepthL1ByHand) {
  // gt:       1.0  2.0      rendered: 1.1  0 (missing)
  //           0    NaN                5.0  1.0
  // Valid gt: the top row. Errors 0.1 m and 2.0 m (the hole counts as depth 0):
  // mean 1.05 m = 105 cm. The bottom row has no ground truth and is skipped.
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const cv::Mat gt = (cv::Mat_<float>(2, 2) << 1.0f, 2.0f, 0.0f, nan);
  const cv::Mat rendered = (cv::Mat_<float>(2, 2) << 1.1f, 0.0f, 5.0f, 1.0f);
  DepthL1Result r;
  std::string why;
  ASSERT_TRUE(compute_depth_l1(rendered, gt, cv::Mat(), &r, &why)) << why;
  EXPECT_NEAR(r.l1_cm, 105.0, 1e-4);
  EXPECT_EQ(r.valid_pixels, 2u);
  EXPECT_EQ(r.missing_rendered, 1u);

  // A mask keeping only the top-left pixel: 10 cm.
  const cv::Mat mask = (cv::Mat_<uchar>(2, 2) << 1, 0, 1, 1);
  ASSERT_TRUE(compute_depth_l1(rendered, gt, mask, &r, &why)) << why;
  EXPECT_NEAR(r.l1_cm, 10.0, 1e-4);
  EXPECT_EQ(r.valid_pixels, 1u);
  EXPECT_EQ(r.missing_rendered, 0u);

  EXPECT_FALSE(compute_depth_l1(rendered, gt, cv::Mat::zeros(2, 2, CV_8UC1), &r, &why));
  EXPECT_NE(why.find("no pixel"), std::string::npos) << why;
}

TEST(ImageMetrics, SegmentationConfusionByHand) {
  // Frame 1, 4 classes (3 never appears), ignore 255:
  //   gt:   0 0 1 1     pred: 0 0 1 0
  //         0 0 1 1           0 1 1 1
  //         2 2 . .           2 2 0 7     (. = 255: skipped whatever is predicted)
  //         2 2 2 .           9 2 2 2     (9 is no class: the "none" column)
  // Frame 2, 1x2:  gt: 1 .   pred: 3 3
  // Confusion (rows gt, columns pred 0..3, none):
  //   0: 3 1 0 0 | 0      1: 1 3 0 1 | 0      2: 0 0 4 0 | 1      3: 0 0 0 0 | 0
  // IoU = TP / (gt + pred - TP): 0: 3/(4+4-3) = 0.6, 1: 3/(5+4-3) = 0.5, 2: 4/(5+4-4) = 0.8,
  // 3: 0/(0+1-0) = 0 (predicted, absent from gt: enters mIoU) -> mIoU = 1.9 / 4 = 0.475.
  // Acc = TP / gt: 3/4, 3/5, 4/5; class 3 has no gt pixel and stays out -> mAcc = 2.15 / 3.
  // Pixel accuracy 10 / 14.
  const cv::Mat gt1 = (cv::Mat_<uchar>(4, 4) << 0, 0, 1, 1, 0, 0, 1, 1, 2, 2, 255, 255, 2, 2, 2, 255);
  const cv::Mat pred1 = (cv::Mat_<uchar>(4, 4) << 0, 0, 1, 0, 0, 1, 1, 1, 2, 2, 0, 7, 9, 2, 2, 2);
  const cv::Mat gt2 = (cv::Mat_<int>(1, 2) << 1, 255);
  const cv::Mat pred2 = (cv::Mat_<int>(1, 2) << 3, 3);
  SegmentationConfig config;
  config.num_classes = 4;
  ConfusionMatrix confusion(4);
  std::string why;
  ASSERT_TRUE(accumulate_confusion(pred1, gt1, config, &confusion, &why)) << why;
  ASSERT_TRUE(accumulate_confusion(pred2, gt2, config, &confusion, &why)) << why;
  EXPECT_EQ(confusion.at(0, 0), 3);
  EXPECT_EQ(confusion.at(0, 1), 1);
  EXPECT_EQ(confusion.at(1, 0), 1);
  EXPECT_EQ(confusion.at(1, 3), 1);
  EXPECT_EQ(confusion.at(2, 4), 1);
  const SegmentationResult r = segmentation_metrics(confusion);
  EXPECT_NEAR(r.iou[0], 0.6, 1e-12);
  EXPECT_NEAR(r.iou[1], 0.5, 1e-12);
  EXPECT_NEAR(r.iou[2], 0.8, 1e-12);
  EXPECT_NEAR(r.iou[3], 0.0, 1e-12);
  EXPECT_EQ(r.classes_in_miou, 4);
  EXPECT_NEAR(r.miou, 0.475, 1e-12);
  EXPECT_TRUE(std::isnan(r.accuracy[3]));
  EXPECT_EQ(r.classes_in_macc, 3);
  EXPECT_NEAR(r.macc, 2.15 / 3.0, 1e-12);
  EXPECT_NEAR(r.pixel_accuracy, 10.0 / 14.0, 1e-12);

  // A class absent from both gt and prediction is left out of both means.
  ConfusionMatrix only_frame1(4);
  ASSERT_TRUE(accumulate_confusion(pred1, gt1, config, &only_frame1, &why)) << why;
  const SegmentationResult r1 = segmentation_metrics(only_frame1);
  EXPECT_TRUE(std::isnan(r1.iou[3]));
  EXPECT_EQ(r1.classes_in_miou, 3);
  EXPECT_NEAR(r1.miou, (0.6 + 0.6 + 0.8) / 3.0, 1e-12);  // class 1: 3/(4+4-3)

  const cv::Mat bad_gt = (cv::Mat_<uchar>(1, 2) << 1, 6);
  EXPECT_FALSE(accumulate_confusion(pred2, bad_gt, config, &confusion, &why));
  EXPECT_NE(why.find("label 6"), std::string::npos) << why;
  EXPECT_EQ(confusion.at(1, 1), 3);  // a rejected frame adds nothing
}

TEST(ImageMetrics, HungarianFindsTheOptimumGreedyMisses) {
  // Greedy takes the cheapest entry (0,0) = 1 and is left with (1,1) = 100: total 101.
  // The optimum is the anti-diagonal: 2 + 2 = 4.
  const std::vector<int> a = solve_assignment({1, 2, 2, 100}, 2, 2);
  EXPECT_EQ(a, (std::vector<int>{1, 0}));
}

TEST(ImageMetrics, HungarianMatchesBruteForce) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  for (const auto& [rows, cols] : std::vector<std::pair<int, int>>{{4, 4}, {3, 5}, {5, 3}, {1, 4}, {6, 6}}) {
    for (int trial = 0; trial < 20; ++trial) {
      std::vector<double> cost(static_cast<std::size_t>(rows * cols));
      for (double& c : cost) c = uniform(rng);
      const std::vector<int> a = solve_assignment(cost, rows, cols);
      ASSERT_EQ(a.size(), static_cast<std::size_t>(rows));
      double total = 0.0;
      std::vector<bool> used(static_cast<std::size_t>(cols), false);
      int assigned = 0;
      for (int i = 0; i < rows; ++i) {
        if (a[static_cast<std::size_t>(i)] < 0) continue;
        ASSERT_FALSE(used[static_cast<std::size_t>(a[static_cast<std::size_t>(i)])]);
        used[static_cast<std::size_t>(a[static_cast<std::size_t>(i)])] = true;
        total += cost[static_cast<std::size_t>(i * cols + a[static_cast<std::size_t>(i)])];
        ++assigned;
      }
      EXPECT_EQ(assigned, std::min(rows, cols));
      // Brute force over permutations of the larger side.
      const int n = std::max(rows, cols), k = std::min(rows, cols);
      std::vector<int> perm(static_cast<std::size_t>(n));
      std::iota(perm.begin(), perm.end(), 0);
      double best = std::numeric_limits<double>::infinity();
      do {
        double t = 0.0;
        for (int i = 0; i < k; ++i)
          t += rows <= cols ? cost[static_cast<std::size_t>(i * cols + perm[static_cast<std::size_t>(i)])]
                            : cost[static_cast<std::size_t>(perm[static_cast<std::size_t>(i)] * cols + i)];
        best = std::min(best, t);
      } while (std::next_permutation(perm.begin(), perm.end()));
      EXPECT_NEAR(total, best, 1e-12) << rows << "x" << cols << " trial " << trial;
    }
  }
}

TEST(ImageMetrics, InstanceMatchingByHand) {
  //   gt ids:  1 1 2 2     predicted ids: 7 7 9 9
  //            1 1 2 2                    7 9 9 9
  //            0 0 3 3                    4 4 4 4     (gt 0 = unannotated: skipped)
  // Areas over annotated pixels: gt 1: 4, 2: 4, 3: 2; pred 7: 3, 9: 5, 4: 2.
  // IoU (pred, gt): (7,1) = 3/(4+3-3) = 0.75, (9,1) = 1/(4+5-1) = 0.125, (9,2) = 4/(4+5-4) = 0.8,
  // (4,3) = 2/(2+2-2) = 1. Best one-to-one: 1-7, 2-9, 3-4 -> mIoU = 2.55 / 3 = 0.85,
  // mAcc = (3/4 + 4/4 + 2/2) / 3 = 0.9166667.
  const cv::Mat gt = (cv::Mat_<int>(3, 4) << 1, 1, 2, 2, 1, 1, 2, 2, 0, 0, 3, 3);
  const cv::Mat pred = (cv::Mat_<ushort>(3, 4) << 7, 7, 9, 9, 7, 9, 9, 9, 4, 4, 4, 4);
  InstanceOverlap overlap;
  std::string why;
  ASSERT_TRUE(accumulate_instance_overlap(pred, gt, InstanceMatchConfig{}, &overlap, &why)) << why;
  const InstanceMatchResult r = match_instances(overlap);
  EXPECT_EQ(r.gt_to_predicted, (std::map<int, int>{{1, 7}, {2, 9}, {3, 4}}));
  EXPECT_NEAR(r.iou.at(1), 0.75, 1e-12);
  EXPECT_NEAR(r.iou.at(2), 0.8, 1e-12);
  EXPECT_NEAR(r.miou, 0.85, 1e-12);
  EXPECT_NEAR(r.macc, 2.75 / 3.0, 1e-12);
  EXPECT_EQ(r.unmatched_predicted, 0u);

  // More predictions than instances: gt 1 1 2 2 vs pred 5 6 6 8. IoU (5,1) = 1/2, (6,1) = 1/3,
  // (6,2) = 1/3, (8,2) = 1/2: the match 1-5, 2-8 sums to 1, leaving 6 unmatched; mIoU 0.5.
  InstanceOverlap second;
  ASSERT_TRUE(accumulate_instance_overlap((cv::Mat_<int>(1, 4) << 5, 6, 6, 8),
                                          (cv::Mat_<int>(1, 4) << 1, 1, 2, 2),
                                          InstanceMatchConfig{}, &second, &why))
      << why;
  const InstanceMatchResult r2 = match_instances(second);
  EXPECT_EQ(r2.gt_to_predicted, (std::map<int, int>{{1, 5}, {2, 8}}));
  EXPECT_NEAR(r2.miou, 0.5, 1e-12);
  EXPECT_NEAR(r2.macc, 0.5, 1e-12);
  EXPECT_EQ(r2.unmatched_predicted, 1u);

  // An instance no prediction overlaps scores 0 and counts in the mean.
  InstanceOverlap third;
  ASSERT_TRUE(accumulate_instance_overlap((cv::Mat_<int>(1, 3) << 5, 5, 5),
                                          (cv::Mat_<int>(1, 3) << 1, 1, 2),
                                          InstanceMatchConfig{}, &third, &why))
      << why;
  const InstanceMatchResult r3 = match_instances(third);
  EXPECT_EQ(r3.gt_to_predicted, (std::map<int, int>{{1, 5}}));
  EXPECT_NEAR(r3.iou.at(2), 0.0, 1e-12);
  EXPECT_NEAR(r3.miou, (2.0 / 3.0) / 2.0, 1e-12);
}

// The simulated click: the pixel farthest from the outline, with the image border an outline.
TEST(ImageMetrics, ClickPointStaysOffTheImageBorder) {
  // A wall the view cuts at the top: rows 0-39 of a 100 x 60 view, full width. Without the
  // border as outline the farthest pixel from its (bottom) edge would be on row 0.
  cv::Mat wall = cv::Mat::zeros(60, 100, CV_8UC1);
  wall.rowRange(0, 40).setTo(255);
  cv::Point at;
  ASSERT_TRUE(click_point(wall, 2.0, &at));
  EXPECT_NEAR(at.y, 19.5, 1.5) << "halfway between the border and the outline";
  EXPECT_GE(at.x, 19);  // at least as far from the left and right borders
  EXPECT_LE(at.x, 80);
  EXPECT_EQ(wall.at<std::uint8_t>(at), 255);

  // A 21 x 21 square well inside: its centre.
  cv::Mat square = cv::Mat::zeros(60, 100, CV_8UC1);
  square(cv::Rect(60, 10, 21, 21)).setTo(1);
  ASSERT_TRUE(click_point(square, 2.0, &at));
  EXPECT_EQ(at, cv::Point(70, 20));

  // A sliver one pixel wide is never at least 2 px in; an empty mask has no click.
  cv::Mat sliver = cv::Mat::zeros(60, 100, CV_8UC1);
  sliver.col(50).setTo(255);
  EXPECT_FALSE(click_point(sliver, 2.0, &at));
  EXPECT_FALSE(click_point(cv::Mat::zeros(60, 100, CV_8UC1), 2.0, &at));
}

}  // namespace
}  // namespace fslam::core
