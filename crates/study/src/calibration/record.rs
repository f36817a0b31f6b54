//! One calibration fit ([`CalibrationRecord`]) and where its view came from ([`ViewSource`]).

use nalgebra::Vector3;
use nerfsv_sim::{ErrorSample, ViewPose};
use serde::{Deserialize, Serialize};

/// Where a calibration view comes from; its name ([`ViewSource::name`]) is the `source` of the
/// fits' CSV and of its JSON.
#[derive(nerfsv_derive::Choice, Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ViewSource {
    /// The route capture rendered by the ground truth.
    #[serde(rename = "route")]
    Route,
    /// The dataset's held-out split.
    #[serde(rename = "held_out")]
    HeldOut,
    /// A recorded route capture (`[calibration] route_dataset`).
    #[serde(rename = "route_dataset")]
    RouteDataset,
}

/// One fit of one calibration view.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibrationRecord {
    pub source: ViewSource,
    pub view: usize,
    pub fit: usize,
    pub route_fraction: Option<f64>,
    pub at: ViewPose,
    /// The fit's pose minus the true pose, [`AXES`](nerfsv_sim::perception::AXES)' order.
    pub error: [f64; 6],
    /// The fit's colour RMSE, variance factor and renders.
    pub rmse: f64,
    pub variance_factor: f64,
    pub renders: usize,
}

impl CalibrationRecord {
    pub fn sample(&self) -> ErrorSample {
        ErrorSample { view: self.view, at: self.at, error: self.error }
    }

    pub fn position_error_m(&self) -> f64 {
        Vector3::new(self.error[0], self.error[1], self.error[2]).norm()
    }

    pub fn rotation_error_deg(&self) -> f64 {
        Vector3::new(self.error[3], self.error[4], self.error[5]).norm().to_degrees()
    }
}
