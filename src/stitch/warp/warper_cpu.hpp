#pragma once
#include <opencv2/core.hpp>

#include "stitch/warp/warper.hpp"

namespace stitch {

// Camera coordinates of the pixels of `part` (in roi coordinates) of a view, CV_32F each.
// `displacement` (CV_32FC2, part-sized, output pixels) moves each pixel before the lookup;
// empty means none. Pixels behind the camera map far outside it (transparent).
void camera_maps(const ViewPlacement& view, const Rect& part, const cv::Mat& displacement,
                 cv::Mat& map_x, cv::Mat& map_y);

class WarperCpu final : public Warper {
 public:
  void prepare(const std::vector<ViewPlacement>& views) override;
  void warp(int index, const ImageView& src, const ImageView& dst) override;
  // Only the pixels of `part` (roi coordinates) of the full roi-sized `dst`: the same values
  // warp() gives there.
  void warp_part(int index, const ImageView& src, const ImageView& dst, const Rect& part);
  // The pixels of `part` (roi coordinates) written to `dst` (part-sized, e.g. a window of the
  // output): the same values warp() gives there.
  void warp_part_to(int index, const ImageView& src, const Rect& part, uint8_t* dst, std::size_t pitch);
  Backend backend() const override { return Backend::Cpu; }

 private:
  struct Maps {
    cv::Mat xy, frac;
  };
  std::vector<Maps> maps_;
};

}  // namespace stitch
