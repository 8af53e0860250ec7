# The whole test suite in a container: the same command CI runs (.ci/run -> scripts/test.sh).
FROM debian:12
WORKDIR /opt/tendril
COPY . .
RUN scripts/install-deps.sh --tests
CMD ["scripts/test.sh"]
