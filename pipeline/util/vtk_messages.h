#pragma once
/// @file vtk_messages.h
/// Catches the error and warning messages VTK prints (from any VTK object: readers, their
/// XML parsers, executives, compressors, render windows), so a failure becomes one clear
/// vx::Error instead of VTK's log on stderr. Internal to the pipeline (VTK includes).

#include <vtkAlgorithm.h>
#include <vtkCommand.h>
#include <vtkLogger.h>
#include <vtkOutputWindow.h>
#include <vtkSmartPointer.h>

#include <atomic>
#include <string>
#include <vector>

namespace vx {

/// While alive, VTK's messages are collected here, not printed. Not thread-safe (VTK's output
/// window is global): use it around one VTK call sequence on the main thread.
class VtkMessageCapture {
 public:
  VtkMessageCapture() : previous_(vtkOutputWindow::GetInstance()), log_level_(vtkLogger::GetCurrentVerbosityCutoff()) {
    window_ = vtkSmartPointer<Window>::New();
    vtkOutputWindow::SetInstance(window_);
    vtkLogger::SetStderrVerbosity(vtkLogger::VERBOSITY_OFF);
  }
  ~VtkMessageCapture() {
    vtkOutputWindow::SetInstance(previous_);
    vtkLogger::SetStderrVerbosity(log_level_);
  }
  VtkMessageCapture(const VtkMessageCapture&) = delete;
  VtkMessageCapture& operator=(const VtkMessageCapture&) = delete;

  /// Error messages so far, each reduced to VTK's own text (without file/line/object prefix).
  [[nodiscard]] const std::vector<std::string>& errors() const { return window_->errors; }
  [[nodiscard]] const std::vector<std::string>& warnings() const { return window_->warnings; }
  /// The first error, or `fallback` when there was none.
  [[nodiscard]] std::string first_error(const std::string& fallback) const {
    return errors().empty() ? fallback : errors().front();
  }

  /// "ERROR: In /path/file.cxx, line N\nvtkClass (0x...): text\n\n" -> "text".
  static std::string clean(const char* raw) {
    std::string m = raw ? raw : "";
    while (!m.empty() && (m.back() == '\n' || m.back() == ' ')) m.pop_back();
    if (m.rfind("ERROR: In ", 0) == 0 || m.rfind("Warning: In ", 0) == 0) {
      const auto nl = m.find('\n');
      if (nl != std::string::npos) m = m.substr(nl + 1);
    }
    if (m.rfind("vtk", 0) == 0) {
      const auto colon = m.find("): ");
      if (colon != std::string::npos && colon < 80) m = m.substr(colon + 3);
    }
    return m;
  }

 private:
  class Window : public vtkOutputWindow {
   public:
    static Window* New() { return new Window; }
    void DisplayText(const char*) override {}
    void DisplayErrorText(const char* t) override { errors.push_back(clean(t)); }
    void DisplayWarningText(const char* t) override { warnings.push_back(clean(t)); }
    void DisplayGenericWarningText(const char* t) override { warnings.push_back(clean(t)); }
    void DisplayDebugText(const char*) override {}
    std::vector<std::string> errors;
    std::vector<std::string> warnings;
  };
  vtkSmartPointer<vtkOutputWindow> previous_;
  vtkLogger::Verbosity log_level_;
  vtkSmartPointer<Window> window_;
};

/// Watches VTK filters without VTK's global output window, so it may be used on any thread
/// (a display surface decimated beside a window's rendering): collects the errors of the
/// filters it watches (their ErrorEvent, which VTK then does not print) and, while they run,
/// sets their abort flag once `cancel` turns true (their ProgressEvent).
class VtkFilterWatch : public vtkCommand {
 public:
  static VtkFilterWatch* New() { return new VtkFilterWatch; }
  /// Watches `filter` from now on; `cancel` may be null (never).
  void watch(vtkAlgorithm* filter, const std::atomic<bool>* cancel = nullptr) {
    cancel_ = cancel;
    filter->AddObserver(vtkCommand::ErrorEvent, this);
    filter->AddObserver(vtkCommand::ProgressEvent, this);
  }
  void Execute(vtkObject* caller, unsigned long event, void* data) override {
    if (event == vtkCommand::ErrorEvent) {
      errors.push_back(VtkMessageCapture::clean(static_cast<const char*>(data)));
    } else if (event == vtkCommand::ProgressEvent && cancel_ && cancel_->load(std::memory_order_relaxed)) {
      if (auto* a = vtkAlgorithm::SafeDownCast(caller)) a->SetAbortExecute(1);
      cancelled = true;
    }
  }
  /// The first error, or `fallback` when there was none.
  [[nodiscard]] std::string first_error(const std::string& fallback) const {
    return errors.empty() ? fallback : errors.front();
  }
  std::vector<std::string> errors;
  bool cancelled{false};

 private:
  const std::atomic<bool>* cancel_{nullptr};
};

}  // namespace vx
