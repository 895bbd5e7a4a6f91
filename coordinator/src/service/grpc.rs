//! The `sylva.v1.Coordinator` API: each call handed to the module of the
//! resource it acts on ([`super::jobs`], [`super::workers`]), as
//! Flamenco's `api_impl` is split. Each call first checks its caller's
//! role ([`crate::access`]); ownership is the resource's to check.

use super::{CoordinatorService, EventStream, Role};
use sylva_proto::pb;
use sylva_proto::pb::coordinator_server::Coordinator;
use tonic::{Request, Response, Status, Streaming};

#[tonic::async_trait]
impl Coordinator for CoordinatorService {
    async fn submit_job(
        &self,
        request: Request<Streaming<pb::SubmitChunk>>,
    ) -> Result<Response<pb::JobId>, Status> {
        {
            self.allowed(&request, &[Role::Admin, Role::Submitter], "submit jobs").await?;
            self.submit(request).await
        }
    }

    type WatchJobStream = EventStream;

    async fn watch_job(
        &self,
        request: Request<pb::JobId>,
    ) -> Result<Response<Self::WatchJobStream>, Status> {
        {
            self.allowed(&request, &[Role::Admin, Role::Submitter], "watch jobs").await?;
            self.watch(request).await
        }
    }

    async fn fetch_result(
        &self,
        request: Request<pb::FetchRequest>,
    ) -> Result<Response<pb::FetchReply>, Status> {
        {
            self.allowed(&request, &[Role::Admin, Role::Submitter], "fetch results").await?;
            self.fetch(request).await
        }
    }

    async fn cancel_job(
        &self,
        request: Request<pb::JobId>,
    ) -> Result<Response<pb::JobSummary>, Status> {
        {
            self.allowed(&request, &[Role::Admin, Role::Submitter], "cancel jobs").await?;
            self.cancel(request).await
        }
    }

    async fn list_jobs(
        &self,
        request: Request<pb::ListJobsRequest>,
    ) -> Result<Response<pb::JobList>, Status> {
        {
            self.allowed(&request, &[Role::Admin, Role::Submitter], "list jobs").await?;
            self.jobs(request).await
        }
    }

    async fn set_priority(
        &self,
        request: Request<pb::SetPriorityRequest>,
    ) -> Result<Response<pb::JobSummary>, Status> {
        {
            self.allowed(&request, &[Role::Admin, Role::Submitter], "change priorities").await?;
            self.reprioritise(request).await
        }
    }

    async fn requeue_job(
        &self,
        request: Request<pb::JobId>,
    ) -> Result<Response<pb::JobId>, Status> {
        {
            self.allowed(&request, &[Role::Admin, Role::Submitter], "requeue jobs").await?;
            self.requeue(request).await
        }
    }

    async fn list_workers(
        &self,
        request: Request<pb::ListWorkersRequest>,
    ) -> Result<Response<pb::WorkerList>, Status> {
        {
            self.allowed(&request, &[Role::Admin, Role::Submitter], "list workers").await?;
            self.workers(request).await
        }
    }

    async fn register_worker(
        &self,
        request: Request<pb::RegisterWorkerRequest>,
    ) -> Result<Response<pb::RegisterWorkerReply>, Status> {
        {
            self.allowed(&request, &[Role::Admin, Role::Worker], crate::registration::REGISTER)
                .await?;
            self.register(request).await
        }
    }
}
