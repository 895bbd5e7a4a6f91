//! Sylva's wire format, generated from `proto/sylva/v1/*.proto`.

pub mod auth;
pub mod tls;

/// Package `sylva.v1`.
pub mod pb {
    tonic::include_proto!("sylva.v1");

    /// The encoded file descriptors, for gRPC server reflection.
    pub const FILE_DESCRIPTOR_SET: &[u8] = tonic::include_file_descriptor_set!("sylva_descriptor");
}
