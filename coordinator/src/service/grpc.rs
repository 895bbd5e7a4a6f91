//! The `sylva.v1.Coordinator` API: each call handed to the module of the
//! resource it acts on ([`super::jobs`], [`super::workers`]), as
//! Flamenco's `api_impl` is split.

use super::{CoordinatorService, EventStream};
use sylva_proto::pb;
use sylva_proto::pb::coordinator_server::Coordinator;
use tonic::{Request, Response, Status, Streaming};

#[tonic::async_trait]
impl Coordinator for CoordinatorService {
    async fn submit_job(
        &self,
        request: Request<Streaming<pb::SubmitChunk>>,
    ) -> Result<Response<pb::JobId>, Status> {
        self.submit(request).await
    }

    type WatchJobStream = EventStream;

    async fn watch_job(
        &self,
        request: Request<pb::JobId>,
    ) -> Result<Response<Self::WatchJobStream>, Status> {
        self.watch(request).await
    }

    async fn fetch_result(
        &self,
        request: Request<pb::FetchRequest>,
    ) -> Result<Response<pb::FetchReply>, Status> {
        self.fetch(request).await
    }

    async fn cancel_job(
        &self,
        request: Request<pb::JobId>,
    ) -> Result<Response<pb::JobSummary>, Status> {
        self.cancel(request).await
    }

    async fn list_jobs(
        &self,
        request: Request<pb::ListJobsRequest>,
    ) -> Result<Response<pb::JobList>, Status> {
        self.jobs(request).await
    }

    async fn set_priority(
        &self,
        request: Request<pb::SetPriorityRequest>,
    ) -> Result<Response<pb::JobSummary>, Status> {
        self.reprioritise(request).await
    }

    async fn list_workers(
        &self,
        request: Request<pb::ListWorkersRequest>,
    ) -> Result<Response<pb::WorkerList>, Status> {
        self.workers(request).await
    }

    async fn register_worker(
        &self,
        request: Request<pb::RegisterWorkerRequest>,
    ) -> Result<Response<pb::RegisterWorkerReply>, Status> {
        self.register(request).await
    }
}
