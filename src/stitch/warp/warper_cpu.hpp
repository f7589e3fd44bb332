#pragma once
#include <opencv2/core.hpp>

#include "stitch/warp/warper.hpp"

namespace stitch {

class WarperCpu final : public Warper {
 public:
  void prepare(const std::vector<ViewPlacement>& views) override;
  void warp(int index, const ImageView& src, const ImageView& dst) override;
  Backend backend() const override { return Backend::Cpu; }

 private:
  struct Maps {
    cv::Mat xy, frac;
  };
  std::vector<Maps> maps_;
};

}  // namespace stitch
