#include <chrono>
#include <cstdio>
#include <map>

#include <opencv2/imgcodecs.hpp>

#include "rolamos/error.hpp"
#include "rolamos/objects.hpp"

namespace rolamos {

ObjectEvaluation EvaluateObjects(const ObjectModel& model, const std::string& data_dir,
                                 const ProgressFn& progress) {
  return EvaluateObjects(model, ReadLabelledFolder(data_dir), progress, data_dir);
}

ObjectEvaluation EvaluateObjects(const ObjectModel& model, const LabelledImages& data, const ProgressFn& progress,
                                 const std::string& data_dir) {
  const auto start = std::chrono::steady_clock::now();
  ObjectEvaluation e;
  e.classes = model.classes();
  std::map<std::string, int> index;
  for (size_t i = 0; i < e.classes.size(); ++i) index[e.classes[i]] = static_cast<int>(i);
  // A background folder is scored as "no class wins" (every SVM below zero).
  const bool background = std::find(data.classes.begin(), data.classes.end(), kBackgroundClass) != data.classes.end();
  if (background) {
    index[kBackgroundClass] = static_cast<int>(e.classes.size());
    e.classes.push_back(kBackgroundClass);
  }
  for (const auto& c : data.classes)
    if (!index.count(c))
      Fail(data_dir + "/" + c, "is a class the model does not know (it knows: " + [&] {
        std::string s;
        for (const auto& k : model.classes()) s += (s.empty() ? "" : ", ") + k;
        return s;
      }() + ")");
  const size_t k = e.classes.size();
  e.confusion.assign(k, std::vector<int>(k, 0));
  // In batches, so memory holds a batch of images and not the whole split.
  const size_t batch = 64;
  for (size_t first = 0; first < data.files.size(); first += batch) {
    const size_t last = std::min(data.files.size(), first + batch);
    std::vector<cv::Mat> images;
    for (size_t i = first; i < last; ++i) {
      images.push_back(cv::imread(data.files[i], cv::IMREAD_COLOR));
      if (images.back().empty()) Fail(data.files[i], "cannot be read as an image (unreadable, truncated or not an image)");
    }
    const auto scores = model.ClassifyAll(images);
    for (size_t i = first; i < last; ++i) {
      const auto& s = scores[i - first];
      const int truth = index[data.classes[static_cast<size_t>(data.labels[i])]];
      const int predicted = background && s.front().score < 0 ? index[kBackgroundClass] : index[s.front().label];
      ++e.confusion[static_cast<size_t>(truth)][static_cast<size_t>(predicted)];
    }
    if (progress) progress(double(last) / double(std::max<size_t>(1, data.files.size())));
  }
  int correct = 0;
  e.precision.assign(k, 0);
  e.recall.assign(k, 0);
  e.support.assign(k, 0);
  for (size_t i = 0; i < k; ++i) {
    int column = 0;
    for (size_t j = 0; j < k; ++j) {
      e.support[i] += e.confusion[i][j];
      column += e.confusion[j][i];
    }
    correct += e.confusion[i][i];
    e.precision[i] = column ? double(e.confusion[i][i]) / column : 0;
    e.recall[i] = e.support[i] ? double(e.confusion[i][i]) / e.support[i] : 0;
  }
  e.images = static_cast<int>(data.files.size());
  e.accuracy = e.images ? double(correct) / e.images : 0;
  e.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return e;
}

std::string FormatEvaluation(const ObjectEvaluation& e) {
  std::string out;
  char line[512];
  std::snprintf(line, sizeof line, "accuracy: %.1f %% (%d images, %.1f s)\n\n", 100 * e.accuracy, e.images, e.seconds);
  out += line;
  size_t width = 5;
  for (const auto& c : e.classes) width = std::max(width, c.size());
  std::snprintf(line, sizeof line, "%-*s  %9s  %6s  %7s\n", int(width), "class", "precision", "recall", "images");
  out += line;
  for (size_t i = 0; i < e.classes.size(); ++i) {
    std::snprintf(line, sizeof line, "%-*s  %8.1f%%  %5.1f%%  %7d\n", int(width), e.classes[i].c_str(),
                  100 * e.precision[i], 100 * e.recall[i], e.support[i]);
    out += line;
  }
  out += "\nconfusion (rows: true class, columns: predicted, in the order above)\n";
  for (size_t i = 0; i < e.classes.size(); ++i) {
    std::snprintf(line, sizeof line, "%-*s ", int(width), e.classes[i].c_str());
    out += line;
    for (size_t j = 0; j < e.classes.size(); ++j) {
      std::snprintf(line, sizeof line, " %4d", e.confusion[i][j]);
      out += line;
    }
    out += "\n";
  }
  return out;
}

}  // namespace rolamos
