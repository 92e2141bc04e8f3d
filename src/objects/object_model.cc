#include <atomic>
#include <chrono>
#include <mutex>
#include <filesystem>
#include <numeric>
#include <random>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "objects/bow_features.h"
#include "objects/one_vs_all.h"
#include "rolamos/error.hpp"
#include "rolamos/objects.hpp"
#include "util/files.h"
#include "util/parallel_for.h"

namespace rolamos {

bool ObjectTrainOptions::IsValid(std::string* error) const {
  if (!features.IsValid(error)) return false;
  if (vocabulary < 8 || vocabulary > 10000) {
    *error = "vocabulary size must be in 8..10000 words";
    return false;
  }
  if (kmeans_samples < vocabulary) {
    *error = "k-means needs at least as many sampled descriptors as words";
    return false;
  }
  if (kernel != "chi2" && kernel != "rbf" && kernel != "linear") {
    *error = "kernel \"" + kernel + "\" is not chi2, rbf or linear";
    return false;
  }
  if (kernel == "chi2" && features.encoding != "bow") {
    *error = "the chi-square kernel needs histograms (encoding \"bow\"); VLAD and Fisher vectors take rbf or linear";
    return false;
  }
  if (select_by != "accuracy" && select_by != "balanced") {
    *error = "select_by must be accuracy or balanced, not \"" + select_by + "\"";
    return false;
  }
  if (folds < 2 || folds > 20) {
    *error = "cross-validation folds must be in 2..20";
    return false;
  }
  return true;
}

struct ObjectModel::Impl {
  std::vector<std::string> all_classes;  // as trained, background included
  std::vector<std::string> reported;     // without background
  std::vector<int> reported_index;       // reported[i] is all_classes[reported_index[i]]
  bool has_background = false;
  ObjectFeatureOptions features;
  std::unique_ptr<BowEncoder> encoder;
  OneVsAll svms;
  nlohmann::json training;  // what Describe reports about training

  std::vector<ClassScore> Score(const cv::Mat& image) const {
    const std::vector<double> s = svms.Scores(encoder->Encode(image));
    std::vector<ClassScore> out;
    for (size_t i = 0; i < reported.size(); ++i)
      out.push_back({reported[i], s[static_cast<size_t>(reported_index[i])]});
    std::sort(out.begin(), out.end(), [](const ClassScore& a, const ClassScore& b) { return a.score > b.score; });
    return out;
  }
};

namespace {

cv::Mat ReadSample(const std::string& file) {
  cv::Mat image = cv::imread(file, cv::IMREAD_COLOR);
  if (image.empty()) Fail(file, "cannot be read as an image (unreadable, truncated or not an image)");
  return image;
}

void WriteFeatureOptions(cv::FileStorage& fs, const ObjectFeatureOptions& o) {
  fs << "features" << "{" << "image_size" << o.image_size << "grid_step" << o.grid_step
     << "patch_sizes" << o.patch_sizes << "pyramid_levels" << o.pyramid_levels << "centre_cell" << (o.centre_cell ? 1 : 0) << "encoding" << o.encoding << "descriptor" << o.descriptor << "hue_bins" << o.hue_bins
     << "saturation_bins" << o.saturation_bins << "colour_weight" << o.colour_weight << "pca_dims" << o.pca_dims << "object_view" << (o.object_view ? 1 : 0)
     << "colour_statistics" << (o.colour_statistics ? 1 : 0) << "colour_pca_dims" << o.colour_pca_dims << "spatial_coordinates" << (o.spatial_coordinates ? 1 : 0) << "orientations" << o.orientations << "}";
}

ObjectFeatureOptions ReadFeatureOptions(const cv::FileNode& n) {
  ObjectFeatureOptions o;
  o.image_size = static_cast<int>(n["image_size"]);
  o.grid_step = static_cast<int>(n["grid_step"]);
  o.patch_sizes.clear();
  n["patch_sizes"] >> o.patch_sizes;
  o.pyramid_levels = static_cast<int>(n["pyramid_levels"]);
  o.centre_cell = static_cast<int>(n["centre_cell"]) != 0;
  o.encoding = static_cast<std::string>(n["encoding"]);
  o.descriptor = static_cast<std::string>(n["descriptor"]);
  o.hue_bins = static_cast<int>(n["hue_bins"]);
  o.saturation_bins = static_cast<int>(n["saturation_bins"]);
  o.colour_weight = static_cast<double>(n["colour_weight"]);
  // Added after the first models: absent there, which means the defaults of then.
  if (!n["pca_dims"].empty()) o.pca_dims = static_cast<int>(n["pca_dims"]);
  o.object_view = !n["object_view"].empty() && static_cast<int>(n["object_view"]) != 0;
  o.colour_statistics = !n["colour_statistics"].empty() && static_cast<int>(n["colour_statistics"]) != 0;
  if (!n["colour_pca_dims"].empty()) o.colour_pca_dims = static_cast<int>(n["colour_pca_dims"]);
  o.spatial_coordinates = !n["spatial_coordinates"].empty() && static_cast<int>(n["spatial_coordinates"]) != 0;
  o.orientations = n["orientations"].empty() ? 1 : static_cast<int>(n["orientations"]);
  return o;
}

// Training facts go into the model as a FileStorage tree (a JSON text would not survive YAML).
void WriteJson(cv::FileStorage& fs, const std::string& key, const nlohmann::json& j) {
  if (j.is_object()) {
    fs << key << "{";
    for (const auto& [k, v] : j.items()) WriteJson(fs, k, v);
    fs << "}";
  } else if (j.is_number_integer()) {
    fs << key << j.get<int>();
  } else if (j.is_number()) {
    fs << key << j.get<double>();
  } else if (j.is_string()) {
    fs << key << j.get<std::string>();
  }
}

nlohmann::json ReadJson(const cv::FileNode& n) {
  if (n.isMap()) {
    nlohmann::json out = nlohmann::json::object();
    for (const auto& child : n) out[child.name()] = ReadJson(child);
    return out;
  }
  if (n.isInt()) return static_cast<int>(n);
  if (n.isReal()) return static_cast<double>(n);
  if (n.isString()) return static_cast<std::string>(n);
  return nullptr;
}

}  // namespace

ObjectModel ObjectModel::Train(const std::string& data_dir, const ObjectTrainOptions& options,
                               const ProgressFn& progress) {
  return Train(ReadLabelledFolder(data_dir), options, progress, data_dir);
}

ObjectModel ObjectModel::Train(const LabelledImages& data, const ObjectTrainOptions& options,
                               const ProgressFn& progress, const std::string& data_dir) {
  std::string error;
  if (!options.IsValid(&error)) Fail("object training options", error);
  const auto start = std::chrono::steady_clock::now();
  auto impl = std::make_shared<Impl>();
  impl->all_classes = data.classes;
  impl->features = options.features;
  for (size_t c = 0; c < data.classes.size(); ++c) {
    if (data.classes[c] == kBackgroundClass) {
      impl->has_background = true;
      continue;
    }
    impl->reported.push_back(data.classes[c]);
    impl->reported_index.push_back(static_cast<int>(c));
  }
  if (impl->reported.empty()) Fail(data_dir, "holds only the background class: nothing to identify");
  if (data.classes.size() < 2) Fail(data_dir, "needs at least two classes (or a class and background)");
  const int n = static_cast<int>(data.files.size());

  // 1. Vocabulary: k-means (or the Fisher codebooks) over descriptors sampled evenly from every
  // training image, in every view the encoder describes.
  const ObjectFeatureOptions& f = options.features;
  const int per_image = std::max(1, options.kmeans_samples / n);
  std::vector<cv::Mat> sampled(static_cast<size_t>(n)), sampled_colour(static_cast<size_t>(n)), sampled_where(static_cast<size_t>(n));
  std::atomic<int> done{0};
  ParallelFor(n, [&](long long item, int) {
    const int i = static_cast<int>(item);
    cv::Mat desc, colour, where;
    for (const SampleView& view : DescribeViews(ReadSample(data.files[static_cast<size_t>(i)]), f)) {
      desc.push_back(view.descriptors);
      colour.push_back(view.colour);
      where.push_back(PlaceColumns(view.where, f.image_size));  // as spatial_coordinates appends them
    }
    std::vector<int> order(static_cast<size_t>(desc.rows));
    std::iota(order.begin(), order.end(), 0);
    std::mt19937 rng(options.seed + static_cast<unsigned>(i));
    std::shuffle(order.begin(), order.end(), rng);
    order.resize(static_cast<size_t>(std::min(per_image, desc.rows)));
    auto pick = [&](const cv::Mat& from) {
      cv::Mat out(static_cast<int>(order.size()), from.cols, CV_32F);
      for (size_t k = 0; k < order.size(); ++k) from.row(order[k]).copyTo(out.row(static_cast<int>(k)));
      return out;
    };
    sampled[static_cast<size_t>(i)] = pick(desc);
    sampled_where[static_cast<size_t>(i)] = pick(where);
    if (f.colour_statistics) sampled_colour[static_cast<size_t>(i)] = pick(colour);
    if (progress) progress(0.4 * ++done / n);
  });
  cv::Mat all;
  cv::vconcat(sampled, all);
  sampled.clear();
  const int kmeans_samples = all.rows;
  if (progress) progress(0.4);
  if (f.encoding == "fisher") {
    cv::Mat appended;
    if (f.spatial_coordinates) cv::vconcat(sampled_where, appended);
    const FisherCodebook book = BuildFisherCodebook(all, options.vocabulary, f.pca_dims, options.seed, appended);
    FisherCodebook colour;
    if (f.colour_statistics) {
      cv::Mat all_colour;
      cv::vconcat(sampled_colour, all_colour);
      colour = BuildFisherCodebook(all_colour, options.vocabulary, f.colour_pca_dims, options.seed, appended);
    }
    impl->encoder = std::make_unique<BowEncoder>(f, book.gmm, book.pca, colour);
  } else {
    impl->encoder = std::make_unique<BowEncoder>(f, BuildVocabulary(all, options.vocabulary, options.seed));
  }
  all.release();
  if (progress) progress(0.5);

  // 2. Every training image as a bag of words, through the same Encode that classification uses.
  cv::Mat x(n, impl->encoder->dims(), CV_32F);
  done = 0;
  ParallelFor(n, [&](long long item, int) {
    const int i = static_cast<int>(item);
    impl->encoder->Encode(ReadSample(data.files[static_cast<size_t>(i)])).copyTo(x.row(i));
    if (progress) progress(0.5 + 0.3 * ++done / n);
  });

  // 3. One SVM per class, parameters cross-validated on the training set.
  std::vector<bool> negatives_only(data.classes.size(), false);
  for (size_t c = 0; c < data.classes.size(); ++c) negatives_only[c] = data.classes[c] == kBackgroundClass;
  OneVsAllOptions svm_options;
  svm_options.kernel = options.kernel;
  svm_options.folds = options.folds;
  svm_options.select_by = options.select_by;
  svm_options.seed = options.seed;
  impl->svms.Train(x, data.labels, static_cast<int>(data.classes.size()), negatives_only, svm_options,
                   [&](int step, int total) {
                     if (progress) progress(0.8 + 0.2 * step / std::max(1, total));
                   });
  std::vector<int> counts(data.classes.size(), 0);
  for (int l : data.labels) ++counts[static_cast<size_t>(l)];
  nlohmann::json per_class = nlohmann::json::object();
  for (size_t c = 0; c < data.classes.size(); ++c) per_class[data.classes[c]] = counts[c];
  impl->training = {{"images", per_class},
                    {"vocabulary", options.vocabulary},
                    {"kmeans_samples", kmeans_samples},
                    {"kernel", options.kernel},
                    {"folds", options.folds},
                    {"select_by", options.select_by},
                    {"seed", static_cast<int>(options.seed)},
                    {"seconds", std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count()}};
  ObjectModel model;
  model.impl_ = impl;
  return model;
}

void ObjectModel::Save(const std::string& path) const {
  const std::string tmp = TemporarySibling(path) + (path.size() > 3 && path.substr(path.size() - 3) == ".gz" ? ".yml.gz" : ".yml");
  {
    cv::FileStorage fs(tmp, cv::FileStorage::WRITE);
    if (!fs.isOpened()) Fail(path, "cannot be written");
    fs << "format" << kObjectModelFormat << "version" << kObjectModelVersion;
    fs << "classes" << impl_->all_classes;
    WriteFeatureOptions(fs, impl_->features);
    WriteJson(fs, "training", impl_->training);
    fs << "vocabulary" << impl_->encoder->vocabulary();
    if (!impl_->encoder->pca().empty()) fs << "pca" << impl_->encoder->pca();
    if (impl_->features.colour_statistics)
      fs << "colour_pca" << impl_->encoder->colour_codebook().pca << "colour_gmm" << impl_->encoder->colour_codebook().gmm;
    impl_->svms.Write(fs);
    fs.release();
  }
  RenameFile(tmp, path);
}

ObjectModel ObjectModel::Load(const std::string& path) {
  if (!std::filesystem::is_regular_file(path)) Fail(path, "no such model file");
  auto impl = std::make_shared<Impl>();
  try {
    cv::FileStorage fs(path, cv::FileStorage::READ);
    if (!fs.isOpened()) Fail(path, "is not a model file OpenCV can read");
    if (static_cast<std::string>(fs["format"]) != kObjectModelFormat)
      Fail(path, "is not a rolamos object model (no \"format: " + std::string(kObjectModelFormat) + "\")");
    const int version = static_cast<int>(fs["version"]);
    if (version < kObjectModelOldestVersion || version > kObjectModelVersion)
      Fail(path, "is an object model of format version " + std::to_string(version) + "; this rolamos reads versions " +
                     std::to_string(kObjectModelOldestVersion) + " to " + std::to_string(kObjectModelVersion) +
                     " (train it again)");
    fs["classes"] >> impl->all_classes;
    impl->features = ReadFeatureOptions(fs["features"]);
    std::string error;
    if (!impl->features.IsValid(&error)) Fail(path, "feature settings: " + error);
    cv::Mat vocabulary, pca;
    FisherCodebook colour;
    fs["vocabulary"] >> vocabulary;
    if (impl->features.encoding == "fisher") {
      fs["pca"] >> pca;
      FisherCodebook book{pca, vocabulary};
      const int appended = impl->features.spatial_coordinates ? 2 : 0;
      if (!book.IsValid(DescriptorSize(impl->features), appended)) Fail(path, "holds no valid Fisher codebook");
      if (impl->features.colour_statistics) {
        fs["colour_pca"] >> colour.pca;
        fs["colour_gmm"] >> colour.gmm;
        if (!colour.IsValid(96, appended)) Fail(path, "holds no valid colour statistics codebook");
      }
    } else if (vocabulary.empty() || vocabulary.cols != DescriptorSize(impl->features) || vocabulary.type() != CV_32F) {
      Fail(path, "holds no valid vocabulary");
    }
    impl->encoder = std::make_unique<BowEncoder>(impl->features, vocabulary, pca, colour);
    impl->training = ReadJson(fs["training"]);
    impl->svms.Read(fs.root(), path);
  } catch (const cv::Exception& e) {
    Fail(path, std::string("is truncated or damaged (") + e.err + ")");
  }
  const size_t svms = static_cast<size_t>(impl->svms.classes());
  if (impl->all_classes.size() < 2 || svms != impl->all_classes.size())
    Fail(path, "lists " + std::to_string(impl->all_classes.size()) + " classes but holds " +
                   std::to_string(svms) + " SVMs");
  for (size_t c = 0; c < impl->all_classes.size(); ++c) {
    if (impl->all_classes[c] == kBackgroundClass) {
      impl->has_background = true;
      continue;
    }
    impl->reported.push_back(impl->all_classes[c]);
    impl->reported_index.push_back(static_cast<int>(c));
  }
  ObjectModel model;
  model.impl_ = impl;
  return model;
}

const std::vector<std::string>& ObjectModel::classes() const { return impl_->reported; }

const ObjectFeatureOptions& ObjectModel::features() const { return impl_->features; }

std::vector<ClassScore> ObjectModel::Classify(const cv::Mat& image) const {
  if (image.empty()) Fail("classify", "empty image");
  return impl_->Score(image);
}

std::vector<std::vector<ClassScore>> ObjectModel::ClassifyAll(const std::vector<cv::Mat>& images) const {
  std::vector<std::vector<ClassScore>> out(images.size());
  ParallelFor(static_cast<long long>(images.size()),
              [&](long long i, int) { out[static_cast<size_t>(i)] = Classify(images[static_cast<size_t>(i)]); });
  return out;
}

nlohmann::json ObjectModel::Describe() const {
  const ObjectFeatureOptions& f = impl_->features;
  nlohmann::json svms = impl_->svms.Describe(), per_class = nlohmann::json::object();
  for (size_t c = 0; c < impl_->all_classes.size(); ++c) per_class[impl_->all_classes[c]] = svms["classes"][c];
  svms["classes"] = per_class;
  return {{"format", kObjectModelFormat},
          {"version", kObjectModelVersion},
          {"classes", impl_->reported},
          {"background", impl_->has_background},
          {"features",
           {{"image_size", f.image_size}, {"grid_step", f.grid_step}, {"patch_sizes", f.patch_sizes},
            {"pyramid_levels", f.pyramid_levels}, {"centre_cell", f.centre_cell}, {"encoding", f.encoding}, {"descriptor", f.descriptor}, {"hue_bins", f.hue_bins},
            {"saturation_bins", f.saturation_bins}, {"colour_weight", f.colour_weight}, {"pca_dims", f.pca_dims}, {"object_view", f.object_view},
            {"colour_statistics", f.colour_statistics}, {"colour_pca_dims", f.colour_pca_dims}, {"spatial_coordinates", f.spatial_coordinates}, {"orientations", f.orientations},
            {"dims", impl_->encoder->dims()}, {"words", impl_->encoder->vocabulary().rows}}},
          {"training", impl_->training},
          {"svm", svms}};
}

}  // namespace rolamos
