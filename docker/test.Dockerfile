# The whole test suite in a container: the same command CI runs (.ci/run -> scripts/test.sh).
#   podman --runtime runc build --network host --format docker -f docker/test.Dockerfile -t tendril-tests .
FROM debian:12
# bookworm-updates and bookworm-security too, as in docker/Dockerfile (docker/README.md).
COPY docker/debian.sources /etc/apt/sources.list.d/debian.sources
WORKDIR /opt/tendril
COPY . .
RUN rm -f /etc/apt/sources.list \
 && scripts/install-deps.sh --tests \
 && apt-get clean && rm -rf /var/lib/apt/lists/*
CMD ["scripts/test.sh"]
