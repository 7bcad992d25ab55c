"""Stateless replicas on a shared content-addressed store (`serve --store s3://...`), against a
real S3-protocol server on loopback: moto's server (PyPI `moto[server]`) with authentication on,
so wrong credentials are refused as S3 refuses them. Uploads and bakes on one replica are
published under their SHA-256; another replica fetches, verifies and serves them bit for bit.
Bad configuration (unreachable store, refused credentials, a missing bucket, a corrupt object, a
URL that names no store) keeps the replica alive and unready, with the reason in /readyz and in
its log, and a repaired store makes it ready without a restart."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import boto3
import httpx
import pytest
from conftest import Server, free_port

BUCKET = "lumigraph-assets"
PREFIX = "e2e"
VIEW = {
    "eye": [0.4, 0.8, 3.2],
    "target": [0, 0, 0],
    "up": [0, 1, 0],
    "yfov_deg": 40,
    "width": 96,
    "height": 80,
}
CUBE_OFF = (
    b"OFF\n8 6 0\n"
    + b"".join(f"{x} {y} {z}\n".encode() for x in (-1, 1) for y in (-1, 1) for z in (-1, 1))
    + b"4 0 1 3 2\n4 4 6 7 5\n4 0 4 5 1\n4 2 3 7 6\n4 0 2 6 4\n4 1 5 7 3\n"
)


@dataclass
class S3:
    endpoint: str
    key_id: str
    secret: str

    def client(self, secret: str | None = None) -> Any:  # boto3's clients are untyped
        return boto3.client(
            "s3",
            endpoint_url=self.endpoint,
            aws_access_key_id=self.key_id,
            aws_secret_access_key=secret or self.secret,
            region_name="us-east-1",
        )

    def env(self, secret: str | None = None, endpoint: str | None = None) -> dict[str, str]:
        return {
            "AWS_ENDPOINT_URL": endpoint or self.endpoint,
            "AWS_ACCESS_KEY_ID": self.key_id,
            "AWS_SECRET_ACCESS_KEY": secret or self.secret,
            "AWS_REGION": "us-east-1",
        }


@pytest.fixture(scope="module")
def s3(tmp_path_factory: pytest.TempPathFactory) -> Iterator[S3]:
    """moto's S3 server on a free loopback port. Its first three requests (creating a user, its
    policy and its key) run unauthenticated; every request after them must be signed with that
    key."""
    moto = shutil.which("moto_server", path=os.path.dirname(sys.executable))
    assert moto, "moto_server is missing: scripts/test_service_e2e.sh installs moto[server]"
    port = free_port()
    log = (tmp_path_factory.mktemp("moto") / "moto.log").open("wb")
    env = dict(os.environ, INITIAL_NO_AUTH_ACTION_COUNT="3")
    proc = subprocess.Popen([moto, "-H", "127.0.0.1", "-p", str(port)], stdout=log,
                            stderr=subprocess.STDOUT, env=env)  # fmt: skip
    endpoint = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 30
        while True:
            with contextlib.suppress(httpx.TransportError):
                httpx.get(f"{endpoint}/moto-api/", timeout=2)
                break
            assert proc.poll() is None and time.monotonic() < deadline, "moto_server did not start"
            time.sleep(0.2)
        iam = boto3.client(
            "iam",
            endpoint_url=endpoint,
            aws_access_key_id="bootstrap",
            aws_secret_access_key="bootstrap",
            region_name="us-east-1",
        )
        iam.create_user(UserName="replica")
        policy = {
            "Version": "2012-10-17",
            "Statement": [{"Effect": "Allow", "Action": "s3:*", "Resource": "*"}],
        }
        iam.put_user_policy(UserName="replica", PolicyName="assets", PolicyDocument=json.dumps(policy))
        key = iam.create_access_key(UserName="replica")["AccessKey"]
        store = S3(endpoint, key["AccessKeyId"], key["SecretAccessKey"])
        store.client().create_bucket(Bucket=BUCKET)
        yield store
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        log.close()


@contextlib.contextmanager
def replica(
    tmp: Path,
    name: str,
    env: dict[str, str],
    url: str = f"s3://{BUCKET}/{PREFIX}",
    seed: Path | None = None,
    ready: bool = True,
) -> Iterator[Server]:
    """A `serve --store URL` with `env` set, an assets folder of its own (holding `seed`, if
    given, as `local.lfa`: a replica with an asset of its own bakes no demo)."""
    assets = tmp / name
    assets.mkdir()
    if seed is not None:
        shutil.copyfile(seed, assets / "local.lfa")
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)  # Server copies the environment when it starts the process
    try:
        server = Server(assets, tmp / f"{name}.log", None, ["--store", url])
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    try:
        if ready:
            server.wait_ready()
        yield server
    finally:
        server.stop()


def render_png(server: Server, asset: str) -> bytes:
    response = httpx.post(
        f"{server.base_url}/v1/assets/{asset}/render?codec=png", json={"view": VIEW}, timeout=60
    )
    assert response.status_code == 200, response.text
    return response.content


def unready_reason(server: Server, timeout: float = 60) -> str:
    """/readyz's message once it names a reason other than loading (the process stays up)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert server.proc.poll() is None, f"the replica exited:\n{server.log_tail()}"
        with contextlib.suppress(httpx.TransportError):
            assert httpx.get(f"{server.base_url}/healthz", timeout=5).status_code == 200
            response = httpx.get(f"{server.base_url}/readyz", timeout=5)
            assert response.status_code == 503, response.text
            message = response.json()["error"]["message"]
            if message.startswith("not ready"):
                return str(message)
        time.sleep(0.2)
    raise AssertionError(f"no reason in /readyz after {timeout} s:\n{server.log_tail()}")


def test_replicas_share_uploads_and_bakes_through_the_store(s3: S3, tmp_path: Path, demo_lfa: Path) -> None:
    client = s3.client()
    data = demo_lfa.read_bytes()
    digest = hashlib.sha256(data).hexdigest()
    with replica(tmp_path, "a", s3.env(), seed=demo_lfa) as a:
        created = httpx.post(f"{a.base_url}/v1/assets?id=shared", content=data, timeout=60)
        assert created.status_code == 201, created.text
        # Published under its hash, create-only, and named.
        blob = client.get_object(Bucket=BUCKET, Key=f"{PREFIX}/sha256/{digest}.lfa")["Body"].read()
        assert blob == data
        record = json.loads(
            client.get_object(Bucket=BUCKET, Key=f"{PREFIX}/names/shared.json")["Body"].read()
        )
        assert record == {"sha256": digest, "bytes": len(data)}
        frame_a = render_png(a, "shared")

        # A replica started afterwards with an empty folder loads it from the store (and bakes
        # no demo: the store has assets), verified, into its cache named by the hash.
        with replica(tmp_path, "b", s3.env()) as b:
            assert [x["id"] for x in httpx.get(f"{b.base_url}/v1/assets").json()] == ["shared"]
            assert (b.assets / ".store-cache" / "sha256" / f"{digest}.lfa").read_bytes() == data
            assert not (b.assets / "demo.lfa").exists()
            assert render_png(b, "shared") == frame_a

            # A bake on b is published too; a (started before it) loads it on first use.
            response = httpx.post(
                f"{b.base_url}/v1/bake",
                files={"mesh": ("cube.off", CUBE_OFF, "application/octet-stream")},
                data={"options": json.dumps({"cameras": 12, "resolution": 32}), "id": "cube"},
                timeout=60,
            )
            assert response.status_code == 202, response.text
            job = response.json()
            deadline = time.monotonic() + 120
            while job["state"] not in ("done", "failed") and time.monotonic() < deadline:
                time.sleep(0.2)
                job = httpx.get(f"{b.base_url}/v1/jobs/{job['id']}").json()
            assert job["state"] == "done", job
            baked = (b.assets / "cube.lfa").read_bytes()
            record = json.loads(
                client.get_object(Bucket=BUCKET, Key=f"{PREFIX}/names/cube.json")["Body"].read()
            )
            assert record["sha256"] == hashlib.sha256(baked).hexdigest()
            assert httpx.get(f"{a.base_url}/v1/assets/cube", timeout=60).status_code == 200
            assert render_png(a, "cube") == render_png(b, "cube")

            # An id the store names is taken on every replica, even one that has not loaded it.
            taken = httpx.post(f"{a.base_url}/v1/assets?id=cube", content=data, timeout=60)
            assert taken.status_code == 409, taken.text

        # Deleting removes the name (the content stays: other names may share it); a replica
        # that never loaded it gets 404.
        assert httpx.delete(f"{a.base_url}/v1/assets/cube", timeout=30).status_code == 204
        names = client.list_objects_v2(Bucket=BUCKET, Prefix=f"{PREFIX}/names/")
        assert sorted(o["Key"] for o in names.get("Contents", [])) == [f"{PREFIX}/names/shared.json"]
        with replica(tmp_path, "c", s3.env()) as c:
            assert httpx.get(f"{c.base_url}/v1/assets/cube", timeout=30).status_code == 404
            assert render_png(c, "shared") == frame_a
    client.delete_object(Bucket=BUCKET, Key=f"{PREFIX}/names/shared.json")


@pytest.mark.parametrize("case", ["credentials", "unreachable", "no-bucket", "bad-url"])
def test_bad_store_configuration_fails_readiness_with_the_reason(
    s3: S3, tmp_path: Path, demo_lfa: Path, case: str
) -> None:
    url = f"s3://{BUCKET}/{PREFIX}"
    env = s3.env()
    expected = {
        "credentials": "refused the credentials",
        "unreachable": "failed to list",
        "no-bucket": "failed to list",
        "bad-url": "bad --store",
    }[case]
    if case == "credentials":
        env = s3.env(secret="not-the-secret")
    elif case == "unreachable":
        env = s3.env(endpoint=f"http://127.0.0.1:{free_port()}")
    elif case == "no-bucket":
        url = "s3://no-such-bucket/x"
    else:
        url = "gs://bucket/x"
    with replica(tmp_path, case, env, url=url, seed=demo_lfa, ready=False) as server:
        reason = unready_reason(server)
        assert expected in reason, reason
        # The same reason in the log, once, as an error line.
        deadline = time.monotonic() + 10
        while expected not in server.log_tail(200) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert expected in server.log_tail(200)
        # A request for an asset is refused with the same reason, never a crash.
        response = httpx.post(f"{server.base_url}/v1/assets/local/render", json={"view": VIEW}, timeout=30)
        assert response.status_code == 503
        assert server.proc.poll() is None


def test_a_corrupt_object_fails_readiness_until_repaired(s3: S3, tmp_path: Path, demo_lfa: Path) -> None:
    client = s3.client()
    data = demo_lfa.read_bytes()
    digest = hashlib.sha256(data).hexdigest()
    prefix = "corrupt"
    blob = f"{prefix}/sha256/{digest}.lfa"
    client.put_object(
        Bucket=BUCKET,
        Key=f"{prefix}/names/scene.json",
        Body=json.dumps({"sha256": digest, "bytes": len(data)}).encode(),
    )
    damaged = bytearray(data)
    damaged[len(damaged) // 2] ^= 0xFF
    client.put_object(Bucket=BUCKET, Key=blob, Body=bytes(damaged))
    # A name record that is not a record costs its own asset only.
    client.put_object(Bucket=BUCKET, Key=f"{prefix}/names/junk.json", Body=b"not a record")
    with replica(tmp_path, "r", s3.env(), url=f"s3://{BUCKET}/{prefix}", ready=False) as server:
        reason = unready_reason(server)
        assert "corrupt object" in reason and digest in reason, reason
        assert not list((server.assets / ".store-cache" / "sha256").iterdir()), "nothing is kept"
        # Repaired in the store: the replica retries and becomes ready without a restart.
        client.put_object(Bucket=BUCKET, Key=blob, Body=data)
        server.wait_ready(timeout=60)
        assert "the asset store works again" in server.log_tail(200)
        assert render_png(server, "scene")
        assert "skipping an asset the store names badly" in server.log_tail(200)
        junk = httpx.get(f"{server.base_url}/v1/assets/junk", timeout=30)
        assert junk.status_code == 503 and "bad record" in junk.json()["error"]["message"], junk.text
        assert httpx.delete(f"{server.base_url}/v1/assets/junk", timeout=30).status_code == 204
        names = client.list_objects_v2(Bucket=BUCKET, Prefix=f"{prefix}/names/")
        assert [o["Key"] for o in names.get("Contents", [])] == [f"{prefix}/names/scene.json"]
