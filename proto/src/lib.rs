//! Sylva's wire format, generated from `proto/sylva/v1/*.proto` ([`pb`]):
//! typed values converted to and from it in one place ([`convert`]), bearer
//! tokens and the worker identity proof ([`auth`]), TLS ([`tls`]), and the
//! process-level helpers both services share: the lock policy ([`sync`])
//! and a process's own folder ([`workdir`]).
//!
//! ```
//! use sylva_proto::pb;
//! use sylva_scene::frame::FrameSettings;
//! let frame = FrameSettings::default();
//! let wire = pb::FrameSettings::from(&frame);
//! assert_eq!(FrameSettings::try_from(&wire).unwrap(), frame);
//! ```

pub mod auth;
pub mod convert;
pub mod sync;
pub mod tls;
pub mod workdir;

/// Package `sylva.v1`.
pub mod pb {
    tonic::include_proto!("sylva.v1");

    /// The encoded file descriptors, for gRPC server reflection.
    pub const FILE_DESCRIPTOR_SET: &[u8] = tonic::include_file_descriptor_set!("sylva_descriptor");
}

/// Server reflection in both protocol versions (`grpc.reflection.v1`, and
/// `v1alpha`, which grpcurl and Python's grpcio still speak), listing just
/// `services` and the health service.
pub fn reflection(
    services: &[&str],
) -> Result<
    (
        tonic_reflection::server::v1::ServerReflectionServer<
            impl tonic_reflection::server::v1::ServerReflection,
        >,
        tonic_reflection::server::v1alpha::ServerReflectionServer<
            impl tonic_reflection::server::v1alpha::ServerReflection,
        >,
    ),
    tonic_reflection::server::Error,
> {
    let builder = || {
        let b = tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(pb::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
            .with_service_name("grpc.health.v1.Health");
        services.iter().fold(b, |b, s| b.with_service_name(*s))
    };
    Ok((builder().build_v1()?, builder().build_v1alpha()?))
}
