#include "engine/keyframe_job.h"

#include "util/cpu_time.h"

namespace rolamos {

KeyframeProducts RunKeyframeJob(const KeyframeJob& job, const KeyframeTools& tools) {
  KeyframeProducts out;
  CpuLaps cpu;
  // The spatio-temporal filter: the frame before (not blended itself) averaged in where the two
  // agree, then the bilateral filter. A keyframe right after another has no such frame: blending
  // averages the two already.
  if (job.blend) {
    cv::Mat image = job.frame->image;
    if (tools.temporal && job.before && !job.before->image.empty() && job.before->image.size() == image.size())
      image = tools.pre->Temporal(image, job.before->image, job.to_before);
    if (tools.bilateral) image = tools.pre->Bilateral(image);
    out.image = image;
  }
  out.filter_seconds = 1e-9 * cpu.Lap();
  out.features = tools.features(*job.frame);
  // Nothing reads a blended frame's unfiltered image after this (the patch blends the filtered
  // one): a patch's keyframes hold one image each until it is written, not two.
  if (job.blend) job.frame->image.release();
  cpu.Restart();  // the features are timed where they are found
  // Loop closures within the patch: the older keyframes under this one (their jobs ran before).
  if (out.features && !out.features->empty()) {
    for (const auto& older : job.older) {
      const KeyframeProducts& theirs = older.products.get();
      if (!theirs.features || theirs.features->empty()) continue;
      PatchFrame f;
      f.index = older.index;
      f.to_patch = older.to_patch;
      f.features = theirs.features;
      if (auto link = LinkPair(job.index, *out.features, job.to_patch, f, tools.fit))
        out.loop_links.push_back(std::move(*link));
    }
  }
  out.link_seconds = 1e-9 * cpu.Lap();
  return out;
}

}  // namespace rolamos
