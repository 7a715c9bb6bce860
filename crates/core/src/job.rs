//! The job layer: one call from the bytes of a mesh file to the bytes of
//! the smoothed file and its full quality report. The CLI and the service
//! both go through it, so the same file and parameters give the same mesh
//! and the same report whichever front end ran them.
//!
//! A job is read ([`Input::read`]: parsing with the parameters' reading
//! options and welding, the input's SHA-256), then smoothed
//! ([`Input::smooth`]: the [`pipeline`], the welding's
//! bookkeeping in the report, the per-vertex results, writing, the
//! output's SHA-256). [`run`] does both in one call; the service reads when
//! the upload arrives (a bad file is refused before it is queued) and
//! smooths on a worker thread.

use crate::control::Progress;
use crate::io::{
    self, Document, Format, IoError, ReadLimits, ReadOptions, VertexResults, WriteOptions,
};
use crate::pipeline::{self, PerVertex, SmoothError};
use crate::report::{QualityReport, sha256_hex, wall_parting};
use crate::{Mesh, Params};
use std::sync::atomic::AtomicBool;
use thiserror::Error;

/// A mesh file read for a job: the parsed document and the hash of its
/// bytes.
#[derive(Debug, Clone)]
pub struct Input {
    document: Document,
    sha256: String,
}

/// What a job produced.
#[derive(Debug, Clone)]
pub struct Output {
    /// The smoothed mesh file.
    pub bytes: Vec<u8>,
    /// The format of [`Output::bytes`].
    pub format: Format,
    /// The full quality report, hashes of the input and output filled in.
    pub report: QualityReport,
}

/// Why a job produced no output.
#[derive(Debug, Error)]
pub enum JobError {
    /// The file could not be read.
    #[error(transparent)]
    Read(IoError),
    /// The parameters are invalid or the run was cancelled.
    #[error(transparent)]
    Smooth(#[from] SmoothError),
    /// The smoothed mesh could not be encoded.
    #[error(transparent)]
    Write(IoError),
}

/// The reading options `params` ask for (welding and its tolerance) under
/// `limits`.
pub fn read_options(params: &Params, limits: ReadLimits) -> ReadOptions {
    ReadOptions {
        limits,
        weld: params.weld,
        weld_tolerance: params.weld_tolerance,
    }
}

impl Input {
    /// Reads `bytes` as `format` with the reading options of `params`
    /// (welding) under `limits`, and hashes them.
    pub fn read(
        bytes: &[u8],
        format: Format,
        params: &Params,
        limits: ReadLimits,
    ) -> Result<Input, IoError> {
        let document = io::read_with(bytes, format, &read_options(params, limits))?;
        Ok(Input {
            document,
            sha256: sha256_hex(bytes),
        })
    }

    /// The mesh to smooth (welded when welding ran).
    pub fn mesh(&self) -> &Mesh {
        &self.document.mesh
    }

    /// The format the file was read as.
    pub fn format(&self) -> Format {
        self.document.format
    }

    /// SHA-256 of the file's bytes, lower-case hex.
    pub fn sha256(&self) -> &str {
        &self.sha256
    }

    /// Vertices of the file before welding; `None` when welding joined
    /// nothing or did not run.
    pub fn file_vertices(&self) -> Option<u64> {
        self.document
            .vertex_map
            .as_ref()
            .map(|map| map.len() as u64)
    }

    /// The file's bodies when they touch face to face (shared faces):
    /// glTF meshes alone are bodies of no report ([`crate::io::FileBodies`]).
    fn touching_bodies(&self) -> Option<&io::FileBodies> {
        self.document
            .bodies
            .as_ref()
            .filter(|b| !b.shared.is_empty())
    }

    /// The report's counts of touching bodies.
    fn fill_bodies(&self, report: &mut QualityReport) {
        if let Some(bodies) = self.touching_bodies() {
            report.mesh.touching_bodies = bodies.count as u64;
            report.mesh.shared_faces = bodies.shared.len() as u64;
        }
    }

    /// The parameters as a run on this input uses them: the welding as
    /// done (a `null` request resolved to the format's default).
    pub fn params_as_run(&self, params: &Params) -> Params {
        Params {
            weld: Some(self.document.welded),
            ..params.clone()
        }
    }

    /// Smooths the mesh with `params` and writes it as `format` (with the
    /// per-vertex results when `params.vertex_results` asks and the format
    /// holds them); the report records the welding and both hashes.
    pub fn smooth(
        &self,
        params: &Params,
        format: Format,
        progress: &dyn Progress,
        cancel: &AtomicBool,
    ) -> Result<Output, JobError> {
        let params = self.params_as_run(params);
        let bodies = self.document.bodies.as_ref().map(|b| &b.of_vertex[..]);
        let smoothed = pipeline::run_bodies(self.mesh(), bodies, &params, progress, cancel)?;
        let options = WriteOptions {
            results: params
                .vertex_results
                .then(|| VertexResults::from(&smoothed.per_vertex)),
            ..WriteOptions::default()
        };
        let bytes = io::write_with(&self.document, &smoothed.positions, format, &options)
            .map_err(JobError::Write)?;
        let mut report = smoothed.report;
        report.mesh.file_vertices = self.file_vertices();
        if let Some(bodies) = self.touching_bodies() {
            let parted = wall_parting(self.mesh(), &bodies.shared, &smoothed.positions);
            report.warnings.push(format!(
                "the file holds {} bodies whose surfaces touch face to face along {} shared \
                 faces (segments written into one file): each body was welded and smoothed on \
                 its own, and their shared walls parted by {:.3} on average and {:.3} at most (in \
                 the mesh's units)",
                bodies.count,
                bodies.shared.len(),
                parted.mean,
                parted.max
            ));
            report.walls_parted = Some(parted);
        }
        self.fill_bodies(&mut report);
        report.reproducibility.input_sha256 = Some(self.sha256.clone());
        report.reproducibility.output_sha256 = Some(sha256_hex(&bytes));
        Ok(Output {
            bytes,
            format,
            report,
        })
    }

    /// Measures the mesh as it is, without smoothing: the report's input
    /// stage and mesh statistics, the input's hash filled in.
    pub fn measure(&self, params: &Params) -> QualityReport {
        let mut report = pipeline::measure(self.mesh(), &self.params_as_run(params));
        report.mesh.file_vertices = self.file_vertices();
        self.fill_bodies(&mut report);
        report.reproducibility.input_sha256 = Some(self.sha256.clone());
        report
    }
}

/// A whole job: a mesh file and what to do with it.
#[derive(Debug, Clone)]
pub struct Request<'a> {
    /// The mesh file's bytes.
    pub bytes: &'a [u8],
    /// The format to read them as.
    pub format: Format,
    /// The parameters (validated by the run).
    pub params: &'a Params,
    /// Limits on the file's vertices and faces.
    pub limits: ReadLimits,
    /// The format to write; `None`: the input's.
    pub output_format: Option<Format>,
}

/// Runs `request`: [`Input::read`] then [`Input::smooth`].
pub fn run(
    request: &Request,
    progress: &dyn Progress,
    cancel: &AtomicBool,
) -> Result<Output, JobError> {
    let input = Input::read(
        request.bytes,
        request.format,
        request.params,
        request.limits.clone(),
    )
    .map_err(JobError::Read)?;
    let format = request.output_format.unwrap_or(input.format());
    input.smooth(request.params, format, progress, cancel)
}

/// Re-encodes a job's output `bytes` (in `from`) as `to`: the mesh alone,
/// the way [`io::write`] writes a document in another format. The output
/// was written by a job, so no reading limits apply.
pub fn convert(bytes: &[u8], from: Format, to: Format) -> Result<Vec<u8>, IoError> {
    let unlimited = ReadLimits {
        max_vertices: usize::MAX,
        max_faces: usize::MAX,
    };
    let doc = io::read(bytes, from, &unlimited)?;
    io::write(&doc, doc.mesh.positions(), to)
}

/// The per-vertex results of a run as the writers take them.
impl<'a> From<&'a PerVertex> for VertexResults<'a> {
    fn from(p: &'a PerVertex) -> Self {
        VertexResults {
            label: &p.label,
            mean_curvature: &p.mean_curvature,
            gaussian_curvature: &p.gaussian_curvature,
            displacement: &p.displacement,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn read_options_carry_the_weld_fields() {
        let p = Params {
            weld: Some(false),
            weld_tolerance: 0.002,
            ..Params::default()
        };
        let limits = ReadLimits {
            max_vertices: 7,
            max_faces: 9,
        };
        let o = read_options(&p, limits.clone());
        assert_eq!(o.limits, limits);
        assert_eq!(o.weld, Some(false));
        assert_eq!(o.weld_tolerance, 0.002);
        assert_eq!(
            read_options(&Params::default(), ReadLimits::default()),
            ReadOptions::default()
        );
    }
}
